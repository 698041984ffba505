"""What a policy may see: its images, its own joints and poses, and the point it chose to look at; never the
simulator's answer (the target's position), except in the one preset labelled privileged."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from apr.model.agent import APRAgent, Observation
from apr.model.config import ModelConfig
from apr.reproduce.paper import PAPER_PRESETS
from apr.train.config import PRESETS, ConfigError, TrainConfig, preset
from apr.train.evaluation import fixation_statistics
from apr.train.rollout import EpisodeResult

PRIVILEGED_PRESETS = {"cpu-4d"}
"""Presets whose heads are handed the simulator's target: each says so in its ``apr presets`` line."""


@pytest.mark.parametrize("name", PAPER_PRESETS)
def test_no_paper_preset_hands_a_policy_the_target(name: str) -> None:
    config = preset(name).resolved()
    assert not config.env.reveal_target
    assert config.env.learned_fixation or not config.model.heads_see_fixation
    assert not config.env.observes_fixation or config.env.learned_fixation


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_a_preset_is_handed_the_target_only_if_its_description_says_so(name: str) -> None:
    description, config = PRESETS[name]
    privileged = config.env.reveal_target and config.model.heads_see_fixation
    assert privileged == (name in PRIVILEGED_PRESETS)
    if privileged:
        assert description.startswith("PRIVILEGED") and "target's true centre" in description


def test_heads_that_see_a_fixation_point_the_observation_lacks_are_refused() -> None:
    config = preset("active-target")
    config.model = config.model.replace(heads_see_fixation=True)
    with pytest.raises(ConfigError, match="--model.heads-see-fixation needs a fixation point"):
        config.check()
    config.env.target = "learned"
    config.check()  # the point it chose is the robot's own knowledge
    config.env.reveal_target = True
    with pytest.raises(ConfigError, match="--env.reveal-target needs --env.target env"):
        config.check()


def test_the_heads_input_has_no_fixation_channels_unless_asked_and_refuses_a_missing_point() -> None:
    observation = Observation(torch.zeros(2, 3, 64, 64, 3, dtype=torch.uint8), torch.zeros(2, 3, 6),
                              torch.zeros(2, 9))  # fmt: skip
    assert observation.proprioception(gripper=True, fixation=False).shape == (2, 9)
    with pytest.raises(ValueError, match="the observation has none"):
        observation.proprioception(gripper=True, fixation=True)
    agent = APRAgent(ModelConfig.tiny(heads_see_proprioception=True, heads_see_fixation=False))
    r = torch.zeros(2, agent.config.representation_channels, 16, 16)
    assert agent._head_input(r, observation).shape[1] == agent.config.representation_channels + 9


def test_a_config_saved_before_the_rule_loads_with_what_its_heads_saw() -> None:
    """Before, ``heads_see_proprioception`` gave the heads g, f and f - tip, and every observation held f."""
    saved = json.loads(preset("cpu-4d").to_json())
    del saved["model"]["heads_see_fixation"], saved["env"]["reveal_target"]
    loaded = TrainConfig.from_json(json.dumps(saved))
    assert loaded.model.heads_see_fixation and loaded.env.reveal_target
    saved = json.loads(preset("active-target").to_json())
    del saved["model"]["heads_see_fixation"], saved["env"]["reveal_target"]
    saved["model"]["heads_see_proprioception"] = False  # the paper presets' heads then saw r only
    loaded = TrainConfig.from_json(json.dumps(saved))
    assert not loaded.model.heads_see_fixation and not loaded.env.reveal_target


def test_fixation_statistics_of_known_points() -> None:
    """Two scenes with one object each at 3 cm and 5 cm from the chosen points; the bin centre (0.55, 0, -0.15)
    lies 10 cm from both objects."""
    centres = [np.array([[0.65, 0.0, -0.15]]), np.array([[0.45, 0.0, -0.15]])]
    chosen = [np.array([0.62, 0.0, -0.15]), np.array([0.50, 0.0, -0.15])]
    results = [EpisodeResult(seed=k, fixation_point=point, object_centres=c,
                             fixation_object_distance=float(np.linalg.norm(point - c[0])))
               for k, (point, c) in enumerate(zip(chosen, centres, strict=True))]  # fmt: skip
    stats = fixation_statistics(results)
    assert stats["median_cm"] == pytest.approx(4.0)
    assert stats["spread_x_cm"] == pytest.approx(6.0) and stats["spread_y_cm"] == 0.0
    assert stats["fixed_median_cm"] == pytest.approx(10.0)
    assert 5.0 < stats["uniform_median_cm"] < 25.0 and stats["scenes"] == 2
    assert fixation_statistics([EpisodeResult(seed=0)]) == {}
