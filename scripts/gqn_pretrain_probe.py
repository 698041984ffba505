"""GQN training on the benchmark's scenes before any grasp, probed as it trains (a GPU job).

Does more GQN training, or a wider GQN, give an r that knows where the objects are? In a 600-grasp CPU run the GQN
makes about 3,000 updates of 8 views, and a linear readout of its r finds the object nearest the bin centre no
better than one of an untrained encoder (``docs/benchmarks.md``, the probe table). Here the same encoder and
generator train on the ELBO alone (``APRAgent.gqn_update``) over many rendered scenes, and ``apr probe``'s ridge
readout measures r at intervals on the same held-out scenes. Beside them, the upper bound: the CPU encoder trained end
to end for the answer on all the scenes. Everything runs at once: one process renders the scenes' share per core,
then one process per job shares the GPU.

Writes ``OUT/results.jsonl`` (one line per measurement), ``OUT/<variant>.pt`` (the encoder's and generator's
weights, for a run to start from) and ``OUT/<variant>_predictions.npz`` (held-out views and their predictions).

    python scripts/gqn_pretrain_probe.py --out results/gqn-pretrain --device cuda
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro

from apr.model.agent import APRAgent, Observation
from apr.reproduce.probe import (
    HELDOUT_OFFSET,
    PROBE_SEED,
    Scenes,
    collect_scenes,
    encode,
    error_cm,
    fit_end_to_end,
    fit_linear,
    load_scenes,
    save_scenes,
)
from apr.train.config import preset

VARIANTS: dict[str, dict[str, object]] = {
    "tiny": {},
    "r32-steps6": dict(representation_channels=32, lstm_channels=32, generation_steps=6, canvas_channels=16),
    "r64-steps6": dict(
        encoder_channels=64,
        encoder_narrow_channels=32,
        representation_channels=64,
        lstm_channels=64,
        generation_steps=6,
        latent_channels=3,
        canvas_channels=32,
    ),  # fmt: skip
}
"""Changes to the CPU preset's model: the tiny sizes, and wider states with more generation steps (published small
GQNs that showed objects had states of 64 channels or more and 6 or more steps)."""
LABELS = ("nearest_object_map", "nearest_object_xy", "object_map")
RESERVE_SECONDS = 45


@dataclass
class Args:
    out: Path = Path("results/gqn-pretrain")
    """Where results.jsonl, the weights and the predictions go."""
    preset: str = "cpu-active-learned-4d"
    """The preset whose scenes (environment, views) and model the GQN trains."""
    train_scenes: int = 8_000
    """Training-split scenes the GQN and the upper bound train on (seeds PROBE_SEED + k, as ``apr probe``'s)."""
    heldout_scenes: int = 500
    """Held-out scenes (seeds PROBE_SEED + HELDOUT_OFFSET + k) every error is measured on."""
    probe_scenes: int = 2_000
    """The first this many training scenes fit the ridge readouts (``apr probe --train-scenes``)."""
    processes: int = 16
    """Rendering processes."""
    variants: tuple[str, ...] = tuple(VARIANTS)
    """Model variants to train, one process each."""
    updates: int = 30_000
    """GQN updates per variant (the schedules anneal over them), unless the deadline comes first."""
    batch: int = 32
    """Scenes per GQN update."""
    probes: int = 6
    """Probes per variant, evenly spaced in updates (and one at the deadline)."""
    upper_bound_steps: int = 8_000
    """Adam steps of the end-to-end upper bound (batch 64); 0 skips it."""
    minutes: float = 7.5
    """Everything ends within this many minutes of the start: the jobs stop training ``RESERVE_SECONDS`` before, for
    their last probe and their files."""
    device: str = "cuda"


def render_share(args: tuple) -> Scenes:
    env_config, split, count, first_seed = args
    torch.set_num_threads(1)
    return collect_scenes(env_config, split, count, first_seed)


def render(args: Args, env_config) -> tuple[Scenes, Scenes]:
    """The training and held-out scenes, rendered in ``args.processes`` processes; the same scenes as one process."""

    def shares(split: str, count: int, first: int) -> list[tuple]:
        size = -(-count // args.processes)
        return [(env_config, split, min(size, count - start), first + start) for start in range(0, count, size)]

    with multiprocessing.get_context("spawn").Pool(args.processes) as pool:
        train = pool.map(render_share, shares("train", args.train_scenes, PROBE_SEED))
        heldout = pool.map(render_share, shares("test", args.heldout_scenes, PROBE_SEED + HELDOUT_OFFSET))
    return Scenes.concatenate(train), Scenes.concatenate(heldout)


def record(out: Path, entry: dict) -> None:
    line = json.dumps(entry)
    print(line, flush=True)
    with open(out / "results.jsonl", "a") as file:
        file.write(line + "\n")


def linear_probe(agent: APRAgent, probe_train: Scenes, heldout: Scenes) -> dict[str, float]:
    """Held-out errors (cm) of ridge readouts of r, per label, beside the constant predictor's."""
    r_train = encode(agent, probe_train).to(agent.device)
    r_heldout = encode(agent, heldout).to(agent.device)
    errors = {}
    for label in LABELS:
        y_train = torch.from_numpy(probe_train.labels[label]).to(agent.device)
        y_heldout = torch.from_numpy(heldout.labels[label])
        predicted = fit_linear(r_train, y_train, r_heldout).cpu()
        errors[label] = error_cm(label, predicted, y_heldout, heldout)
        errors[f"{label}_constant"] = error_cm(label, y_train.cpu().mean(0).expand_as(y_heldout), y_heldout, heldout)
    return errors


def gqn_job(variant: str, args: Args, scenes_path: Path, deadline: float) -> None:
    torch.set_num_threads(2)
    train, heldout = load_scenes(scenes_path / "train.npz"), load_scenes(scenes_path / "heldout.npz")
    probe_train = train.take(slice(args.probe_scenes))
    config = preset(args.preset).model.replace(device=args.device, gqn_anneal_updates=args.updates,
                                               **VARIANTS[variant])  # fmt: skip
    agent = APRAgent(config)
    every = {"images": torch.from_numpy(train.images).to(agent.device),
             "viewpoints": torch.from_numpy(train.viewpoints).to(agent.device),
             "gripper": torch.from_numpy(train.gripper).to(agent.device)}  # fmt: skip
    scenes = Observation.from_env(every, agent.device)
    generator = torch.Generator(agent.device).manual_seed(0)
    probe_at = set(np.linspace(0, args.updates, args.probes).astype(int).tolist())
    heldout_views = heldout.observation(slice(0, 256))
    started, metrics = time.time(), {}
    for update in range(args.updates + 1):
        late = time.time() > deadline
        if update in probe_at or late or update == args.updates:
            measure = {k: round(v, 5) for k, v in agent.gqn_measure(heldout_views).items()}
            record(args.out, {"job": "gqn", "variant": variant, "update": update, "views_seen": update * args.batch,
                              "seconds": round(time.time() - started, 1), **linear_probe(agent, probe_train, heldout),
                              **measure, **{k: round(v, 4) for k, v in metrics.items()}})  # fmt: skip
        if late or update == args.updates:
            break
        index = torch.randint(len(scenes), (args.batch,), generator=generator, device=agent.device)
        metrics = agent.gqn_update(scenes[index], update)
    torch.save({"variant": variant, "model": dataclasses.asdict(config), "updates": update,
                "encoder": agent.encoder.state_dict(), "generator": agent.generator.state_dict()},
               args.out / f"{variant}.pt")  # fmt: skip
    views = heldout.observation(slice(0, 8))
    np.savez_compressed(args.out / f"{variant}_predictions.npz", views=heldout.images[:8],
                        predicted=(agent.predict_view(views) * 255).round().astype(np.uint8))  # fmt: skip


def upper_bound_job(args: Args, scenes_path: Path, deadline: float) -> None:
    torch.set_num_threads(2)
    train, heldout = load_scenes(scenes_path / "train.npz"), load_scenes(scenes_path / "heldout.npz")
    config = preset(args.preset).model
    for label in ("nearest_object_map", "nearest_object_xy"):
        for count in sorted({args.probe_scenes, len(train)}):
            if time.time() > deadline:
                return
            started = time.time()
            part = train.take(slice(count))
            y_train, y_heldout = torch.from_numpy(part.labels[label]), torch.from_numpy(heldout.labels[label])
            predicted = fit_end_to_end(config, part, y_train, heldout, args.upper_bound_steps, 0, args.device, 64)
            record(args.out, {"job": "end_to_end", "label": label, "train_scenes": count,
                              "steps": args.upper_bound_steps, "batch": 64, "seconds": round(time.time() - started, 1),
                              "heldout_median_cm": error_cm(label, predicted, y_heldout, heldout),
                              "constant_median_cm": error_cm(label, y_train.mean(0).expand_as(y_heldout), y_heldout,
                                                             heldout)})  # fmt: skip


def main(args: Args) -> None:
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.time()
    env_config = dataclasses.replace(preset(args.preset).env, renderer="tiny")
    train, heldout = render(args, env_config)
    scenes_path = args.out / "scenes"
    scenes_path.mkdir(exist_ok=True)
    save_scenes(train, scenes_path / "train.npz")
    save_scenes(heldout, scenes_path / "heldout.npz")
    record(args.out, {"job": "render", "train_scenes": len(train), "heldout_scenes": len(heldout),
                      "seconds": round(time.time() - started, 1), "env": dataclasses.asdict(env_config)})  # fmt: skip
    deadline = started + 60 * args.minutes - RESERVE_SECONDS
    context = multiprocessing.get_context("spawn")
    jobs = [context.Process(target=gqn_job, args=(variant, args, scenes_path, deadline)) for variant in args.variants]
    if args.upper_bound_steps:
        jobs.append(context.Process(target=upper_bound_job, args=(args, scenes_path, deadline)))
    for job in jobs:
        job.start()
    for job in jobs:
        job.join()
    for path in scenes_path.iterdir():
        path.unlink()
    scenes_path.rmdir()
    print(f"done in {time.time() - started:.0f} s", flush=True)


if __name__ == "__main__":
    main(tyro.cli(Args))
