"""How well the completion monitor's scorers tell a finished task from an unfinished one, and how soon.

    PYTHONPATH=agent:runtime/src python bench/completion_accuracy.py [--samples 800]

Both scorers a simulated cell can run are measured on the same held-out pictures
(``armnet_sim.scene_samples``, a seed neither was tuned or trained on): successes, near
misses (the disc 4-40 px off the pad), far poses and pictures of no scene at all (the
simulator's "no arm attached", a flat colour, noise), each under another light (gain
0.6-1.4, offset -30..30) with sensor noise (sigma up to 8). The labels come from the
scene's geometry, not from a scorer. Printed per scorer: precision and recall of a
frame's hit (target ≥ 0.95 each, issue: unattended evaluation), the near misses it
took for successes, and its CPU time per frame.

Latency: the arm moves from raised to the target in 30 frames and stays; the first
frame clearly complete by geometry is the scene's change, and a scorer's latency is the
number of frames from it to the scorer's first hit (target 0 to 2; a hit while the disc
is still clearly off the pad is a false success, printed as -1; a cell's
``consecutiveFrames`` K adds K - 1 on top, by design).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

HELD_OUT_SEED = 1000
APPROACH_FRAMES = 30
APPROACHES = 8


def region_scorer() -> Any:
    from armnet_connector.completion import build_scorer
    from armnet_core.cell_completion import CompletionConfig
    from armnet_sim.render import target_region
    from armnet_sim.scene_samples import HEIGHT, WIDTH

    left, top, width, height = target_region(WIDTH, HEIGHT)
    return build_scorer(CompletionConfig.model_validate({
        "camera": "front", "scorer": "region",
        "region": {"left": left, "top": top, "width": width, "height": height},
        "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 60},
    }))


def classifier_scorer() -> Any:
    from armnet_connector.completion import build_scorer
    from armnet_core.cell_completion import CompletionConfig
    from armnet_sim.scene_samples import SHIPPED_CLASSIFIER, SHIPPED_CLASSIFIER_INPUT

    return build_scorer(CompletionConfig.model_validate({
        "camera": "front", "scorer": "classifier",
        "classifier": {"model": str(SHIPPED_CLASSIFIER.resolve()), "inputSize": SHIPPED_CLASSIFIER_INPUT},
    }))


def accuracy(scorer: Any, pictures: list[Any]) -> dict[str, float]:
    hits = []
    scorer.score(pictures[0].image)  # a classifier loads its model at its first score: not a frame's cost
    started = time.process_time()
    for picture in pictures:
        hits.append(scorer.score(picture.image).hit)
    cpu_ms = (time.process_time() - started) * 1000 / len(pictures)
    truth = [p.complete for p in pictures]
    true_pos = sum(1 for h, t in zip(hits, truth, strict=True) if h and t)
    precision = true_pos / max(1, sum(hits))
    recall = true_pos / max(1, sum(truth))
    near = [h for h, p in zip(hits, pictures, strict=True) if p.kind == "near_miss"]
    blank = [h for h, p in zip(hits, pictures, strict=True) if p.kind == "no_scene"]
    return {"precision": precision, "recall": recall, "near_miss_hits": sum(near) / max(1, len(near)),
            "no_scene_hits": sum(blank) / max(1, len(blank)), "cpu_ms": cpu_ms}


def latency(scorer: Any, seed: int) -> list[int]:
    """Frames from the scene's change to the scorer's first hit, per approach; -1: a hit while clearly off the pad.

    The change is the first frame clearly complete (the disc ``SUCCESS_MARGIN_PX`` inside
    the pad); a hit in the pixel-wide band before it, where the picture cannot tell, counts
    as on time (0), one before the band as a false success.
    """
    from armnet_sim.scene_samples import (
        NEAR_MISS_PX,
        SUCCESS_MARGIN_PX,
        approach,
        frame_of,
        pad_distance,
        perturb,
    )

    rng = np.random.default_rng(seed)
    delays = []
    for _ in range(APPROACHES):
        start = {"shoulder_lift": rng.uniform(-40, 0), "elbow_flex": rng.uniform(-30, 10),
                 "wrist_flex": rng.uniform(-20, 30)}
        poses = approach(APPROACH_FRAMES, start) + [approach(APPROACH_FRAMES, start)[-1]] * 5
        light = np.random.default_rng(int(rng.integers(1 << 30)))
        distances = [pad_distance(pose) for pose in poses]
        changed = next(i for i, d in enumerate(distances) if d <= -SUCCESS_MARGIN_PX)
        band = next(i for i, d in enumerate(distances) if d < NEAR_MISS_PX[0])
        hit_at = next((i for i, pose in enumerate(poses) if scorer.score(perturb(frame_of(pose), light)).hit), None)
        if hit_at is None:
            delays.append(len(poses))
        elif hit_at < band:
            delays.append(-1)
        else:
            delays.append(max(0, hit_at - changed))
    return delays


def main() -> int:
    from armnet_sim.scene_samples import samples

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=800)
    args = parser.parse_args()
    pictures = samples(HELD_OUT_SEED, args.samples)
    counts = {kind: sum(1 for p in pictures if p.kind == kind) for kind in ("success", "near_miss", "far", "no_scene")}
    print(f"held-out pictures (seed {HELD_OUT_SEED}): {counts}, light and noise varied")
    scorers: dict[str, Callable[[], Any]] = {"region": region_scorer, "classifier": classifier_scorer}
    failed = False
    for name, make in scorers.items():
        scorer = make()
        figures = accuracy(scorer, pictures)
        delays = latency(scorer, HELD_OUT_SEED + 1)
        # A hit before the scene changed is a false success (a negative delay), not a fast one.
        met = figures["precision"] >= 0.95 and figures["recall"] >= 0.95 and all(0 <= d <= 2 for d in delays)
        failed |= not met
        print(f"{name:10s} precision {figures['precision']:.3f}  recall {figures['recall']:.3f}  "
              f"near misses taken for a success {figures['near_miss_hits']:.1%}, no scene {figures['no_scene_hits']:.1%}  "
              f"CPU {figures['cpu_ms']:.2f} ms/frame  latency {delays} frames (max {max(delays)})  "
              f"{'met' if met else 'NOT MET'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
