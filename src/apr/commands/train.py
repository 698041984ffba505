"""``apr train``, ``apr eval`` and ``apr presets``."""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from apr.train.config import PRESETS, TrainConfig, preset


def train(argv: list[str]) -> None:
    """``apr train --preset NAME [--field value ...]`` or ``apr train --resume RUN_DIR [--field value ...]``."""
    from apr.train.trainer import Trainer

    parser = argparse.ArgumentParser(prog="apr train", add_help=False)
    parser.add_argument("--preset", default="active-target", choices=list(PRESETS))
    parser.add_argument("--resume", type=Path, default=None)
    known, rest = parser.parse_known_args(argv)
    if known.resume is not None:
        default = Trainer.saved_config(known.resume)
        config = tyro.cli(TrainConfig, default=default, args=rest, prog="apr train --resume RUN_DIR")
        Trainer.resume(known.resume, config).train()
        return
    config = tyro.cli(TrainConfig, default=preset(known.preset), args=rest, prog=f"apr train --preset {known.preset}",
                      description=f"Train APR. Preset {known.preset}: {PRESETS[known.preset][0]}. "
                      "Any field below overrides the preset; --resume RUN_DIR continues a run.")  # fmt: skip
    run_dir = Trainer(config).train()
    print(f"run folder: {run_dir}")


@dataclass
class EvalArgs:
    """Evaluate a run's latest checkpoint, or a given checkpoint, on held-out objects."""

    path: Annotated[Path, tyro.conf.Positional]
    """A run folder (its latest checkpoint) or a checkpoint file."""
    episodes: int = 100
    """Episodes to run (SPEC: at least 100 per checkpoint)."""
    split: Literal["test", "train"] = "test"
    """Object split: the 100 held-out objects, or the 900 training ones."""
    json: Path | None = None
    """Write the result (rate, 95% interval, per-episode outcomes) to this JSON file."""
    workers: int = 0
    """Environment processes; 0 = the run's number of workers."""


def evaluate(args: EvalArgs) -> None:
    import torch

    from apr.model.agent import APRAgent
    from apr.train.evaluation import evaluate as run_evaluation
    from apr.train.trainer import latest_checkpoint

    checkpoint = args.path if args.path.is_file() else latest_checkpoint(args.path)
    if checkpoint is None or not checkpoint.exists():
        raise SystemExit(f"no checkpoint found at {args.path}")
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    config = TrainConfig.from_json(state["config"])
    agent = APRAgent(config.model)
    agent.load_state_dict(state["agent"])
    result = run_evaluation(agent, config.env, args.episodes, args.split, args.workers or config.workers)
    summary = (f"{checkpoint}: {result.success_rate:.1%} success on {result.episodes} {args.split} episodes "
               f"(95% CI {result.ci_low:.1%}-{result.ci_high:.1%})")  # fmt: skip
    print(summary)
    if args.json:
        payload = {**result.to_dict(), "checkpoint": str(checkpoint), "grasps": state["progress"]["grasps"]}
        args.json.write_text(json.dumps(payload, indent=2))


@dataclass
class PresetsArgs:
    """List the presets and what each changes from active-target."""


def list_presets(_: PresetsArgs) -> None:
    base = _flat(PRESETS["active-target"][1])
    for name, (description, config) in PRESETS.items():
        changes = {k: v for k, v in _flat(config).items() if base.get(k) != v and k != "preset"}
        print(f"{name:34s} {description}")
        if changes and name != "active-target":
            print(" " * 35 + ", ".join(f"{k}={v}" for k, v in changes.items()))


def _flat(config: TrainConfig) -> dict[str, object]:
    flat: dict[str, object] = {}
    for key, value in dataclasses.asdict(config).items():
        if isinstance(value, dict):
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    return flat
