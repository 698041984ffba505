"""Does the passive model's GQN learn where the target is? Its generator trained alone on passive scenes, probed as it
trains, for each layout of the static cameras.

In a 600-grasp run of ``cpu-passive-target`` on ``-v4`` (cameras at the tray's front, left and right), a ridge readout
of r finds the target to 10.4 cm (a constant: 11.6), where the same encoder trained end to end for the answer finds it
to 1.2 cm; and the generator draws the target's mask nowhere (its predicted mask is the mean mask, about 0.02, inside
the target as outside). The paper: "the generator is trained to also reconstruct the mask in this case, forcing the
representation r to preserve the target information" (4A). Here the preset's encoder and generator train on the ELBO
alone (``APRAgent.gqn_update``, batch 8, as many updates as a run makes) on scenes of each environment version, and at
intervals two measures on held-out scenes: how the predicted mask of view 2 (from views 0 and 1) stands out on the
target (its mean on the target's pixels minus its mean elsewhere; 1 is perfect, 0 is none) and a ridge readout of
the target's xy from r (``apr probe``'s). One factor changes at a time: the cameras' layout (``cameras``, the
environment's option), the weight of the mask's channel in the ELBO (``--model.gqn-mask-weight``), or the
generator's size (its kernel and steps: how far across r it carries what a context view shows), or the pixel
sigma's schedule (how much the likelihood asks of the details).

    python scripts/passive_gqn_probe.py --variants sides:1 front:1 sides:10 --out results/passive-cameras/gqn
    python scripts/passive_gqn_probe.py --variants sides:1:lstm_kernel=5,generation_steps=6 \
        sides:1:sigma_start=0.7,sigma_end=0.7 sides:1:sigma_start=0.2,sigma_end=0.2 --out results/passive-cameras/gqn
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro

from apr.envs.config import PASSIVE_CAMERAS
from apr.model.agent import APRAgent, Observation
from apr.reproduce.probe import HELDOUT_OFFSET, PROBE_SEED, Scenes, cached_scenes, probe_entries
from apr.train.config import preset


@dataclass
class Args:
    variants: tuple[str, ...] = ("sides:1", "front:1", "sides:10")
    """CAMERAS:MASK_WEIGHT[:FIELD=NUMBER,...] each: the passive cameras' layout (``sides``: v4's; ``front``), the
    weight of the mask's channel in the ELBO (1: the paper's) and, optionally, numeric fields of the model changed
    from the preset's (``lstm_kernel=5,generation_steps=6``; ``sigma_start=0.7,sigma_end=0.7``)."""
    out: Path = Path("results/passive-cameras/gqn")
    """Where results.jsonl goes (one line per measurement)."""
    preset: str = "cpu-passive-target"
    """The preset whose environment (but its cameras) and model (but the mask's weight) train."""
    train_scenes: int = 600
    heldout_scenes: int = 100
    updates: int = 6_000
    """GQN updates, the schedules (sigma, learning rate) annealed over them (a 600-grasp run of the preset makes
    about 6,000 of 8 views)."""
    batch: int = 8
    probes: int = 4
    """Measurements, evenly spaced in updates (the first before any)."""
    seed: int = 0
    threads: int = 1
    cache: Path = Path("runs/probe-scenes")


def mask_contrast(agent: APRAgent, scenes: Scenes) -> float:
    """The predicted mask of view 2 from views 0 and 1: its mean on the target's pixels minus its mean elsewhere,
    averaged over the scenes."""
    predicted = agent.predict_view(scenes.observation(), query_view=2)[..., 3]
    truth = scenes.images[:, 2, ..., 3] > 127
    return float(np.mean([frame[mask].mean() - frame[~mask].mean()
                          for frame, mask in zip(predicted, truth, strict=True) if mask.any()]))  # fmt: skip


def main(args: Args) -> None:
    torch.set_num_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    config = preset(args.preset).resolved()
    probe_at = set(np.linspace(0, args.updates, args.probes).astype(int).tolist())
    for variant in args.variants:
        cameras, mask_weight, *sizes = variant.split(":")
        overrides = {key: type(getattr(config.model, key))(value)
                     for key, value in (item.split("=") for item in ",".join(sizes).split(",") if item)}  # fmt: skip
        own = PASSIVE_CAMERAS[config.env.env_id.rsplit("-", 1)[1]] == cameras  # "": the version's own, cached alike
        env = dataclasses.replace(config.env, cameras="" if own else cameras)
        train = cached_scenes(env, "train", args.train_scenes, PROBE_SEED, args.cache)
        heldout = cached_scenes(env, "test", args.heldout_scenes, PROBE_SEED + HELDOUT_OFFSET, args.cache)
        weight = float(mask_weight)
        agent = APRAgent(config.model.replace(seed=args.seed, gqn_anneal_updates=args.updates, gqn_mask_weight=weight,
                                              **overrides))  # fmt: skip
        scenes = Observation.from_env({"images": train.images, "viewpoints": train.viewpoints,
                                       "gripper": train.gripper})  # fmt: skip
        generator = torch.Generator().manual_seed(args.seed)
        started = time.time()
        for update in range(args.updates + 1):
            if update in probe_at:
                (probe,) = probe_entries(agent, train, heldout, "", ("target_xy",), ("linear",), 0, args.seed)
                entry = {"cameras": cameras, "mask_weight": weight, **overrides, "update": update,
                         "seconds": round(time.time() - started, 1),
                         "mask_contrast": round(mask_contrast(agent, heldout), 4),
                         "target_xy_ridge_cm": probe["heldout_median_cm"],
                         "target_xy_constant_cm": probe["constant_median_cm"], "train_scenes": len(train),
                         "heldout_scenes": len(heldout), "batch": args.batch}  # fmt: skip
                print(json.dumps(entry), flush=True)
                with open(args.out / "results.jsonl", "a") as file:
                    file.write(json.dumps(entry) + "\n")
            if update == args.updates:
                break
            index = torch.randint(len(scenes), (args.batch,), generator=generator)
            agent.gqn_update(scenes[index], update)


if __name__ == "__main__":
    main(tyro.cli(Args))
