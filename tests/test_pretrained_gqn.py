"""GQN training before the first grasp: the ELBO-only update, and runs starting from its weights."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from apr.model import APRAgent, ModelConfig
from apr.model import pretrained as pretrained_module
from apr.model.pretrained import load_gqn_init, packaged_names, problems
from apr.reproduce.policies import starting_agent
from apr.train.config import ConfigError, preset
from tests.test_model import random_observation


def parameters_of(module: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def changed(before: list[torch.Tensor], module: torch.nn.Module) -> bool:
    return any(not torch.equal(a, b) for a, b in zip(before, module.parameters(), strict=True))


def test_gqn_update_trains_the_encoder_and_generator_only() -> None:
    agent = APRAgent(ModelConfig.tiny())
    before = {name: parameters_of(module) for name, module in agent.networks.items()}
    metrics = agent.gqn_update(random_observation(6, 3, np.random.default_rng(0)), step=0)
    assert {"gqn/elbo_loss", "gqn/nll", "gqn/kl", "gqn/mse", "gqn/sigma", "gqn/lr"} <= metrics.keys()
    assert all(math.isfinite(value) for value in metrics.values())
    assert metrics["gqn/sigma"] == agent.config.sigma_start and metrics["gqn/lr"] == agent.config.gqn_lr_start
    assert changed(before["encoder"], agent.encoder) and changed(before["generator"], agent.generator)
    assert not changed(before["grasp"], agent.grasp) and not changed(before["fixation"], agent.fixation)


def test_gqn_update_needs_a_generator() -> None:
    agent = APRAgent(ModelConfig.tiny(representation=False))
    with pytest.raises(RuntimeError, match="no generator"):
        agent.gqn_update(random_observation(2, 3, np.random.default_rng(0)), step=0)


def save_weights(agent: APRAgent, path: Path) -> Path:
    """A weights file as ``scripts/gqn_pretrain_probe.py`` writes it."""
    torch.save({"model": dataclasses.asdict(agent.config), "updates": 1, "encoder": agent.encoder.state_dict(),
                "generator": agent.generator.state_dict()}, path)  # fmt: skip
    return path


def test_a_model_starts_from_the_weights_and_keeps_its_heads(tmp_path: Path) -> None:
    trained = APRAgent(ModelConfig.tiny(seed=1))
    trained.gqn_update(random_observation(4, 3, np.random.default_rng(0)), step=0)
    path = save_weights(trained, tmp_path / "gqn.pt")
    fresh = APRAgent(ModelConfig.tiny(seed=2, gqn_init=str(path)))
    heads_before = parameters_of(fresh.grasp)
    load_gqn_init(fresh)
    for name in ("encoder", "generator"):
        mine, theirs = fresh.networks[name].state_dict(), trained.networks[name].state_dict()
        assert all(torch.equal(mine[key], theirs[key]) for key in theirs)
    assert not changed(heads_before, fresh.grasp)


def test_without_gqn_init_nothing_is_loaded() -> None:
    agent = APRAgent(ModelConfig.tiny())
    before = parameters_of(agent.encoder)
    load_gqn_init(agent)
    assert not changed(before, agent.encoder)


def test_another_architecture_is_refused_by_name(tmp_path: Path) -> None:
    path = save_weights(APRAgent(ModelConfig.tiny()), tmp_path / "gqn.pt")
    found = problems(ModelConfig.tiny(representation_channels=32, gqn_init=str(path)))
    assert len(found) == 1 and "representation_channels is 16" in found[0]
    assert "--model.representation-channels 16" in found[0]
    with pytest.raises(ValueError, match="representation_channels"):
        load_gqn_init(APRAgent(ModelConfig.tiny(representation_channels=32, gqn_init=str(path))))


def test_missing_damaged_and_foreign_files_are_said_plainly(tmp_path: Path) -> None:
    assert "neither a packaged name" in problems(ModelConfig.tiny(gqn_init=str(tmp_path / "none.pt")))[0]
    damaged = tmp_path / "damaged.pt"
    damaged.write_bytes(b"not a torch file")
    assert "not a readable weights file" in problems(ModelConfig.tiny(gqn_init=str(damaged)))[0]
    foreign = tmp_path / "foreign.pt"
    torch.save({"networks": {}}, foreign)
    assert "not a file of GQN weights" in problems(ModelConfig.tiny(gqn_init=str(foreign)))[0]
    assert "ablation" in problems(ModelConfig.tiny(representation=False, gqn_init=str(foreign)))[0]


def test_a_run_refuses_bad_weights_before_any_work(tmp_path: Path) -> None:
    config = preset("cpu-active-learned-4d")
    config = dataclasses.replace(config, model=config.model.replace(gqn_init=str(tmp_path / "none.pt")))
    with pytest.raises(ConfigError, match="--model.gqn-init"):
        config.check()


@pytest.mark.parametrize("name", packaged_names())
def test_packaged_weights_load_into_the_architecture_they_name(name: str) -> None:
    trained_with = pretrained_module.read(name)["model"]
    config = preset("cpu-active-learned-4d")
    architecture = {field: trained_with[field] for field in pretrained_module.ARCHITECTURE}
    model = config.model.replace(gqn_init=name, **architecture)
    assert problems(model) == []
    agent = starting_agent(dataclasses.replace(config, model=model))
    weights = pretrained_module.read(name)["encoder"]
    assert all(torch.equal(agent.encoder.state_dict()[key], value) for key, value in weights.items())
