"""GQN weights trained on the benchmark's scenes before any grasp, for a run's encoder and generator to start from.

``ModelConfig.gqn_init`` names such a file: a packaged name (``NAME.pt`` in this package's ``pretrained`` folder, whose
README says how each was trained) or a path. ``scripts/gqn_pretrain_probe.py`` writes them: a dict with ``model`` (the
:class:`ModelConfig` fields it was trained with), ``updates``, ``encoder`` and ``generator`` (state dicts). Only the
architecture has to match the run's; the run's own schedules and optimiser start afresh. The paper trains the GQN
from scratch during the grasps; this departs from it (docs/decisions.md, "GQN training before the first grasp").
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

if TYPE_CHECKING:
    from apr.model.agent import APRAgent
    from apr.model.config import ModelConfig

PACKAGED = Path(__file__).parent / "pretrained"
"""The packaged weights: ``PACKAGED / f"{name}.pt"``."""
ARCHITECTURE = ("image_channels", "viewpoint_dim", "gripper_dim", "encoder_channels", "encoder_narrow_channels",
                "representation_channels", "generation_steps", "lstm_channels", "lstm_kernel", "latent_channels",
                "canvas_channels")  # fmt: skip
"""The :class:`ModelConfig` fields that shape the encoder's and generator's weights."""


def packaged_names() -> list[str]:
    return sorted(path.stem for path in PACKAGED.glob("*.pt"))


def resolve(name: str) -> Path:
    """The file ``name`` means: a packaged name, else a path."""
    packaged = PACKAGED / f"{name}.pt"
    return packaged if packaged.is_file() else Path(name)


def read(name: str) -> dict[str, Any]:
    """The contents of ``name``'s file; ValueError with a sentence saying what is wrong."""
    path = resolve(name)
    if not path.is_file():
        raise ValueError(f"{name!r} is neither a packaged name ({', '.join(packaged_names()) or 'none'}) nor a file")
    try:
        contents = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # a damaged or foreign file: say so, whatever torch raised
        raise ValueError(f"{path} is not a readable weights file ({error})") from None
    missing = [key for key in ("model", "encoder", "generator") if key not in contents]
    if missing:
        raise ValueError(f"{path} lacks {', '.join(missing)}: not a file of GQN weights")
    return contents


def problems(config: ModelConfig) -> list[str]:
    """What keeps ``config.gqn_init`` from loading into a model of ``config``, one sentence each (empty: none)."""
    if not config.gqn_init:
        return []
    if not config.representation:
        return ["--model.gqn-init needs the generator: the 'w/o representation' ablation has none"]
    try:
        trained = read(config.gqn_init)["model"]
    except ValueError as error:
        return [f"--model.gqn-init {error}"]
    return [f"--model.gqn-init {config.gqn_init}: its {field} is {trained.get(field)}, this model's "
            f"{getattr(config, field)} (--model.{field.replace('_', '-')} {trained.get(field)})"
            for field in ARCHITECTURE if trained.get(field) != getattr(config, field)]  # fmt: skip


def load_gqn_init(agent: APRAgent) -> None:
    """Load ``agent.config.gqn_init``'s weights into the agent's encoder and generator (nothing if it is empty)."""
    config = agent.config
    found = problems(config)
    if found:
        raise ValueError("\n".join(found))
    if not config.gqn_init:
        return
    contents = read(config.gqn_init)
    agent.encoder.load_state_dict(contents["encoder"])
    agent.generator.load_state_dict(contents["generator"])
