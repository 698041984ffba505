"""Can a grasp head of a given width read where the target is from the tool tip, from what the heads see?

The grasp heads see r with the proprioception g tiled beside it (``ModelConfig.heads_see_proprioception``). A reach
needs the tool tip's offset to the target. This fits readouts of that offset (and of the target's xy) on the frozen
``[r, tiled g]`` of a trained run, on the probe's scenes (``apr probe``: the environment's target, 0 to 6 random grasp
steps; the training split to fit, the held-out objects to measure): ridge regression on the flattened input (the
linear bound), and the policy heads' architecture (a conv block and one linear layer, ``probe.Readout``) at each
width asked, trained for the answer. Where a head the width of the policy's cannot read the offset as well as a
wider one, trained with the answer in hand, the width loses reach precision before any RL signal does.

    python scripts/reach_readout_probe.py results/archive/batch64/cpu-active-target__s0 --widths 16,8,8 64,32,16

Prints one JSON line per (label, readout): held-out median error in cm.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import torch
import tyro

from apr.model.encoder import tile
from apr.reproduce import probe
from apr.reproduce.policies import load_policy


@dataclass
class Args:
    source: Annotated[Path, tyro.conf.Positional]
    """A run folder (its final checkpoint) of an environment-target preset."""
    widths: tuple[str, ...] = ("16,8,8", "32,16,16", "64,32,16", "128,64,32")
    """Conv-block channels of the heads to fit, comma-separated, one width per entry."""
    labels: tuple[str, ...] = ("tip_target_offset", "target_xy")
    """Labels to read."""
    train_scenes: int = 500
    """Training-split scenes the readouts are fitted on."""
    steps: int = 3000
    """Adam steps per head (batch 32)."""
    cache: Path = Path("runs/probe-scenes")
    """The probe's scene cache (``apr probe --cache``)."""


def heads_input(r: torch.Tensor, scenes: probe.Scenes) -> torch.Tensor:
    """(S, R + 9, 16, 16): r with g tiled beside it, as the grasp heads see it (without the steps left)."""
    proprioception = scenes.observation().proprioception(gripper=True, fixation=False)
    return torch.cat([r, tile(proprioception, r.shape[-1])], dim=1)


def main(args: Args) -> None:
    torch.set_num_threads(1)
    snapshot = load_policy(args.source)
    env = dataclasses.replace(snapshot.config.env, renderer="tiny")
    if env.target != "env":
        raise SystemExit(f"{args.source} has no environment target: its scenes have no tip-to-target offset")
    train = probe.cached_scenes(env, "train", args.train_scenes, probe.PROBE_SEED, args.cache)
    heldout = probe.cached_scenes(env, "test", 100, probe.PROBE_SEED + probe.HELDOUT_OFFSET, args.cache)
    x_train = heads_input(probe.encode(snapshot.agent, train), train)
    x_heldout = heads_input(probe.encode(snapshot.agent, heldout), heldout)
    for label in args.labels:
        y_train, y_heldout = torch.from_numpy(train.labels[label]), torch.from_numpy(heldout.labels[label])
        errors = {"constant": probe.median_cm(y_train.mean(0).expand_as(y_heldout), y_heldout),
                  "linear": probe.median_cm(probe.fit_linear(x_train, y_train, x_heldout), y_heldout)}  # fmt: skip
        for width in args.widths:
            channels = tuple(int(channel) for channel in width.split(","))
            predicted = probe.fit_head(x_train, y_train, x_heldout, channels, args.steps, seed=0)
            errors[f"head {width}"] = probe.median_cm(predicted, y_heldout)
        for readout, error in errors.items():
            print(json.dumps({"source": str(args.source), "label": label, "readout": readout,
                              "heldout_median_cm": error, "train_scenes": len(train)}), flush=True)  # fmt: skip


if __name__ == "__main__":
    main(tyro.cli(Args))
