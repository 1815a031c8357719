"""Record a LeRobot dataset on the cell with LeRobot's own ``record()``, teleoperated through armnet.

This is ``lerobot-record`` as a LeRobot user runs it beside a real arm, with the
cell's facts in place of the command-line flags (``_so101_moves.follower_config``:
the port, calibration, cameras and safety limit are the cell's) and armnet's teleop relay as the leader arm.
Until the operator moves the leader (``armnet teleop JOB``, or the cell operator's
page), the follower holds the pose it started in, so an unattended recording still
makes a whole dataset. The dataset lands in the job's output directory
(``$HF_LEROBOT_HOME`` points there), which the platform stores when the job ends:
``armnet artifacts JOB --download DIR`` fetches it.

    armnet run runtime/examples/record.py --embodiment lerobot/so-101 --output /tmp/recorded \\
        --args '{"episodes": 2, "episode_seconds": 3}'
"""

from __future__ import annotations

from typing import Any

from _so101_moves import follower_config
from armnet_runtime import Context, main
from armnet_runtime.lerobot.teleop import ArmnetRelayConfig
from lerobot.robots.so_follower import SO101Follower, SO101FollowerConfig
from lerobot.scripts.lerobot_record import DatasetRecordConfig, RecordConfig, record


def starting_pose(config: SO101FollowerConfig) -> dict[str, float]:
    """The follower's joint positions now, as the action keys LeRobot's robot takes."""
    robot = SO101Follower(config)
    robot.connect()
    try:
        observation = robot.get_observation()
        return {key: float(observation[key]) for key in robot.action_features}
    finally:
        robot.disconnect()


@main
def run(ctx: Context) -> dict[str, Any]:
    robot = follower_config(ctx)
    dataset = record(RecordConfig(
        robot=robot,
        teleop=ArmnetRelayConfig.for_cell(ctx.cell, hold=starting_pose(robot)),
        dataset=DatasetRecordConfig(
            repo_id=str(ctx.args.get("repo_id", "armnet/recording")),
            single_task=ctx.cell.language_instruction or str(ctx.args.get("task", "teleoperated recording")),
            fps=int(ctx.args.get("fps", 10)),
            episode_time_s=float(ctx.args.get("episode_seconds", 3)),
            reset_time_s=float(ctx.args.get("reset_seconds", 1)),
            num_episodes=int(ctx.args.get("episodes", 2)),
            push_to_hub=False,  # the platform stores the output directory; the job reaches no hub
        ),
        play_sounds=False,
    ))
    ctx.report_progress(f"recorded {dataset.meta.total_episodes} episode(s)")
    return {"repo_id": dataset.repo_id, "episodes": dataset.meta.total_episodes,
            "frames": dataset.meta.total_frames, "cameras": sorted(dataset.meta.video_keys)}
