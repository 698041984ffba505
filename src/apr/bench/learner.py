"""``apr bench learner``: the cost of one joint update (ELBO + grasp SAC + fixation SAC) of the APR learner.

Random uint8 observations of the env's shapes feed ``APRAgent.update``; the table gives milliseconds per
update, samples per second (one sample = one grasp transition and one fixation sample) and the FLOPs per
sample counted by ``torch.utils.flop_counter.FlopCounterMode`` (matmuls and convolutions, forward and
backward). torch is imported inside ``run`` so that the CLI starts fast.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    import torch

    from apr.model import Observation


@dataclass
class LearnerBenchArgs:
    """Settings of the learner benchmark."""

    size: Literal["paper", "tiny"] = "tiny"
    """Network sizes: the paper's (GQN tower + 12-step ConvDRAW + 128/64/32 heads) or the tiny test sizes."""
    batch_size: int = 32
    """Grasp transitions per update; the fixation batch has the same size (the paper/SAC value is 256)."""
    gqn_batch_size: int | None = None
    """Observations in the ELBO per update; default: the config's (36 paper, 8 tiny), capped by batch_size."""
    image_channels: int = 3
    """3 (RGB) or 4 (RGB + target mask)."""
    grasp_action_dim: int = 6
    """6-DoF or 4-DoF grasp actions."""
    representation: bool = True
    """False benchmarks the "w/o representation" ablation (no generator; critics train the encoder)."""
    device: str = "auto"
    """"auto" (cuda when available, else cpu), "cpu", "cuda", ..."""
    precision: Literal["fp32", "bf16"] = "fp32"
    """fp32, or bf16 autocast of the forward passes."""
    channels_last: bool = False
    """Channels-last memory format for the convolutions."""
    compile: bool = False
    """torch.compile the encoder and generator (the first warmup iterations then include compilation)."""
    warmup: int = 1
    """Untimed updates before timing (allocator, cuDNN autotuning, compilation)."""
    iterations: int = 3
    """Timed updates."""
    threads: int | None = None
    """CPU threads for torch (default: torch's choice)."""
    seed: int = 0
    """Seed of the agent and of the random observations."""


def _random_observation(batch: int, channels: int, generator: torch.Generator, device: torch.device) -> Observation:
    """Random env-shaped observations: images uint8 (B, 3, 64, 64, C), viewpoints (B, 3, 6), gripper (B, 9),
    fixation (B, 3)."""
    import torch

    from apr.model import Observation

    return Observation(
        images=torch.randint(0, 256, (batch, 3, 64, 64, channels), generator=generator, dtype=torch.uint8).to(device),
        viewpoints=(torch.rand(batch, 3, 6, generator=generator) * 6.28 - 3.14).to(device),
        gripper=(torch.rand(batch, 9, generator=generator) * 2 - 1).to(device),
        fixation=(torch.rand(batch, 3, generator=generator) * 0.5).to(device),
    )


def run(args: LearnerBenchArgs) -> None:
    """Time the joint update with the given settings and print the table."""
    import statistics
    import time

    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from apr.model import APRAgent, FixationBatch, GraspBatch, ModelConfig

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    base = ModelConfig.preset(args.size)
    config = base.replace(
        image_channels=args.image_channels,
        grasp_action_dim=args.grasp_action_dim,
        representation=args.representation,
        batch_size=args.batch_size,
        fixation_batch_size=args.batch_size,
        gqn_batch_size=min(args.gqn_batch_size or base.gqn_batch_size, args.batch_size),
        gqn_fixation_batch_size=min(base.gqn_fixation_batch_size, args.batch_size),
        device=args.device,
        precision=args.precision,
        channels_last=args.channels_last,
        compile=args.compile,
        seed=args.seed,
    )
    agent = APRAgent(config)
    device = agent.device
    generator = torch.Generator().manual_seed(args.seed)
    batch = args.batch_size
    grasp = GraspBatch(
        obs=_random_observation(batch, args.image_channels, generator, device),
        action=(torch.rand(batch, args.grasp_action_dim, generator=generator) * 2 - 1).to(device),
        reward=torch.rand(batch, generator=generator).to(device),
        next_obs=_random_observation(batch, args.image_channels, generator, device),
        terminated=(torch.rand(batch, generator=generator) < 0.2).float().to(device),
    )
    lifted = (torch.rand(batch, generator=generator) < 0.5).float().to(device)
    fixation = FixationBatch(
        obs=_random_observation(batch, args.image_channels, generator, device),
        action=(torch.rand(batch, 3, generator=generator) * 2 - 1).to(device),
        reward=lifted,
        lifted=lifted,  # the grasp started at the point chosen: what hindsight relabelling reads
        grasp_tip=torch.tensor([0.55, 0.0, -0.13]).expand(batch, 3).to(device),
    )

    def synchronize() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    # FLOPs: forward by network (module attribution is reliable in the forward pass), then a whole update.
    counter_agent = agent if not args.compile else APRAgent(config.replace(compile=False))
    with FlopCounterMode(display=False) as forward_counter, torch.no_grad():
        counter_agent.compute_losses(grasp, fixation, step=0)
    forward_by_network = {"TowerEncoder": 0, "ConvDRAWGenerator": 0, "Actor": 0, "TwinCritic": 0}
    for module, counts in forward_counter.get_flop_counts().items():
        if module in forward_by_network:
            forward_by_network[module] = sum(counts.values())
    with FlopCounterMode(display=False) as update_counter:
        counter_agent.update(grasp, fixation, step=0)
    update_flops = update_counter.get_total_flops()

    for step in range(args.warmup):
        agent.update(grasp, fixation, step)
    synchronize()
    times = []
    for step in range(args.warmup, args.warmup + args.iterations):
        start = time.perf_counter()
        agent.update(grasp, fixation, step)
        synchronize()
        times.append(time.perf_counter() - start)

    seconds = statistics.median(times)
    parameters = agent.num_parameters()
    giga = 1e9
    heads_flops = forward_by_network["Actor"] + forward_by_network["TwinCritic"]
    rows = [
        ("ms / joint update (median)", f"{1e3 * seconds:.1f}"),
        ("ms / joint update (min .. max)", f"{1e3 * min(times):.1f} .. {1e3 * max(times):.1f}"),
        ("samples / s", f"{batch / seconds:.1f}"),
        ("GFLOP / sample (fwd + bwd)", f"{update_flops / batch / giga:.2f}"),
        ("  forward: encoder", f"{forward_by_network['TowerEncoder'] / batch / giga:.2f}"),
        ("  forward: generator", f"{forward_by_network['ConvDRAWGenerator'] / batch / giga:.2f}"),
        ("  forward: actors + critics", f"{heads_flops / batch / giga:.2f}"),
        ("achieved GFLOP/s", f"{update_flops / seconds / giga:.1f}"),
    ]
    threads = torch.get_num_threads() if device.type == "cpu" else "-"
    print(
        f"apr bench learner: size={args.size} device={device} precision={args.precision} compile={args.compile} "
        f"channels_last={args.channels_last} cpu_threads={threads} torch={torch.__version__}"
    )
    elbo = (
        f"ELBO on {config.gqn_batch_size} + {config.gqn_fixation_batch_size} observations"
        if args.representation
        else "no ELBO (w/o representation)"
    )
    print(
        f"batch: {batch} grasp + {batch} fixation samples, {elbo} (C={args.image_channels}, "
        f"grasp A={args.grasp_action_dim}); timed {args.iterations} after {args.warmup} warmup"
    )
    print("parameters: " + ", ".join(f"{name} {count / 1e6:.2f}M" for name, count in parameters.items()))
    width = max(len(name) for name, _ in rows)
    print(f"| {'metric':<{width}} | {'value':>15} |")
    print(f"|{'-' * (width + 2)}|{'-' * 17}|")
    for name, value in rows:
        print(f"| {name:<{width}} | {value:>15} |")
