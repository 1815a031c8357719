"""Train the simulated cells' completion classifier on rendered frames and export it as ONNX.

    PYTHONPATH=agent:runtime/src python bench/train_completion_classifier.py            # writes the shipped model
    PYTHONPATH=agent:runtime/src python bench/train_completion_classifier.py --out /tmp/reach.onnx

The model the project ships for its simulated cells (``armnet_sim/data/reach_classifier.onnx``)
comes from this script and nothing else: no weights from a hub, a fixed seed, pictures
the simulator renders (``armnet_sim.scene_samples``: successes, near misses and far poses
under changing light and noise), each turned into the model's input by the one function
the connector scores with (``classifier_input``). Needs torch and onnx (the dev venv);
the connector needs neither, it runs the exported file in OpenCV's DNN module.

The held-out measurement is ``bench/completion_accuracy.py`` (another seed); this script
prints the accuracy on its own validation seed and checks that OpenCV's answers for the
exported file match torch's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

TRAIN_SEED, VALIDATION_SEED = 1, 2


def build_model():  # type: ignore[no-untyped-def]
    """Five stride-2 convolutions down to 3x3 at a 96-pixel input, then one logit: ~30 k weights."""
    from torch import nn

    layers: list[nn.Module] = []
    channels = 3
    for width in (16, 24, 32, 32, 32):
        layers += [nn.Conv2d(channels, width, 3, stride=2, padding=1), nn.ReLU()]
        channels = width
    return nn.Sequential(*layers, nn.Flatten(), nn.Linear(32 * 3 * 3, 1))


def inputs_of(scene_samples: list, size: int) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[type-arg]
    from armnet_connector.classifier_scorer import classifier_input

    x = np.concatenate([classifier_input(s.image, size) for s in scene_samples])
    y = np.array([1.0 if s.complete else 0.0 for s in scene_samples], np.float32)
    return x, y


def main() -> int:
    from armnet_sim.scene_samples import SHIPPED_CLASSIFIER, SHIPPED_CLASSIFIER_INPUT, samples

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=SHIPPED_CLASSIFIER)
    parser.add_argument("--samples", type=int, default=4000)
    parser.add_argument("--epochs", type=int, default=14)
    parser.add_argument("--size", type=int, default=SHIPPED_CLASSIFIER_INPUT)
    args = parser.parse_args()

    import torch

    torch.manual_seed(0)
    torch.set_num_threads(2)
    started = time.monotonic()
    x, y = inputs_of(samples(TRAIN_SEED, args.samples), args.size)
    vx, vy = inputs_of(samples(VALIDATION_SEED, args.samples // 4), args.size)
    print(f"rendered {len(x)} training and {len(vx)} validation pictures in {time.monotonic() - started:.0f} s")
    model = build_model()
    optimiser = torch.optim.Adam(model.parameters(), lr=2e-3)
    loss_of = torch.nn.BCEWithLogitsLoss()
    tx, ty = torch.from_numpy(x), torch.from_numpy(y)
    generator = torch.Generator().manual_seed(0)
    for epoch in range(args.epochs):
        model.train()
        order = torch.randperm(len(tx), generator=generator)
        for start in range(0, len(order), 64):
            batch = order[start:start + 64]
            optimiser.zero_grad()
            loss = loss_of(model(tx[batch]).squeeze(1), ty[batch])
            loss.backward()
            optimiser.step()
        model.eval()
        with torch.no_grad():
            predicted = (model(torch.from_numpy(vx)).squeeze(1) > 0).numpy()
        print(f"epoch {epoch + 1}: loss {loss.item():.4f}, validation accuracy {np.mean(predicted == (vy > 0.5)):.4f}")

    model.eval()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(model, torch.zeros(1, 3, args.size, args.size), str(args.out), dynamo=False,
                      input_names=["frame"], output_names=["logit"], opset_version=13)
    check(args.out, model, vx[:32], args.size)
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes) in {time.monotonic() - started:.0f} s")
    return 0


def check(path: Path, model, inputs: np.ndarray, size: int) -> None:  # type: ignore[no-untyped-def]
    """OpenCV's DNN answers as torch does for the exported file (the connector runs it there)."""
    import torch
    from armnet_connector.classifier_scorer import load_model
    from armnet_core.cell_completion import ClassifierConfig

    net = load_model(ClassifierConfig(model=str(path.resolve()), input_size=size))
    with torch.no_grad():
        expected = model(torch.from_numpy(inputs)).squeeze(1).numpy()
    for blob, want in zip(inputs, expected, strict=True):
        net.setInput(blob[None])
        got = float(np.asarray(net.forward()).reshape(-1)[0])
        if abs(got - float(want)) > 1e-3 * max(1.0, abs(float(want))):
            raise SystemExit(f"OpenCV's answer {got} differs from torch's {want} for the exported model")


if __name__ == "__main__":
    sys.exit(main())
