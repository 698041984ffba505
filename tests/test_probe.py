"""``apr probe``: readouts that recover a known answer, and only a real one; the probe.json it writes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from apr.model.agent import APRAgent
from apr.model.config import ModelConfig
from apr.model.heads import SpatialSoftArgmax
from apr.reproduce import probe
from apr.reproduce.probe import ProbeArgs, Readout, fit_head, fit_linear, median_cm, run
from apr.train.config import ConfigError


def synthetic(count: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Features (count, 4, 4, 4) and labels (count, 2) that are a fixed linear map of them plus a little noise."""
    generator = torch.Generator().manual_seed(seed)
    features = torch.randn(count, 4, 4, 4, generator=generator)
    weights = torch.randn(64, 2, generator=torch.Generator().manual_seed(99)) * 0.01
    return features, features.flatten(1) @ weights + 0.001 * torch.randn(count, 2, generator=generator)


def test_the_linear_probe_recovers_a_linear_answer_and_not_shuffled_labels() -> None:
    features, labels = synthetic(300, seed=0)
    heldout, heldout_labels = synthetic(100, seed=1)
    constant = median_cm(labels.mean(0).expand_as(heldout_labels), heldout_labels)
    recovered = median_cm(fit_linear(features, labels, heldout), heldout_labels)
    shuffled = median_cm(fit_linear(features, labels[torch.randperm(300)], heldout), heldout_labels)
    assert recovered < 0.1 * constant, (recovered, constant)
    assert shuffled > 0.8 * constant, (shuffled, constant)


def test_the_head_readout_learns_the_answer_and_has_the_labels_shape() -> None:
    features, labels = synthetic(300, seed=0)
    heldout, heldout_labels = synthetic(50, seed=1)
    predicted = fit_head(features, labels, heldout, channels=(8, 8), steps=400, seed=0)
    assert predicted.shape == (50, 2)
    constant = median_cm(labels.mean(0).expand_as(heldout_labels), heldout_labels)
    assert median_cm(predicted, heldout_labels) < 0.6 * constant
    assert Readout(16, (16, 8, 8), 16, 3)(torch.zeros(5, 16, 16, 16)).shape == (5, 3)


def test_bad_arguments_are_refused_before_any_work(tmp_path) -> None:
    args = ProbeArgs(source=str(tmp_path / "missing"), labels=("where",), readouts=("cubic",), train_scenes=0,
                     out=tmp_path / "out", cache=tmp_path / "cache")  # fmt: skip
    with pytest.raises(ConfigError) as refused:
        run(args)
    for part in ("--train-scenes", "unknown label 'where'", "unknown readout 'cubic'", "does not exist"):
        assert part in str(refused.value)
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


def test_a_probe_of_an_untrained_encoder_writes_its_entries(tmp_path, one_thread) -> None:
    """``apr probe`` sets torch's threads (one by default); the fixture gives the other tests theirs back."""
    args = ProbeArgs(source="untrained:smoke", train_scenes=10, heldout_scenes=4, readouts=("linear", "head"),
                     steps=5, out=tmp_path / "out", cache=tmp_path / "cache")  # fmt: skip
    path = run(args)
    entries = json.loads(path.read_text())
    assert path == tmp_path / "out" / "untrained-smoke" / "probe.json"
    assert [(e["label"], e["readout"]) for e in entries] == [(label, readout)
                                                              for label in probe.SCENE_LABELS
                                                              for readout in ("linear", "head")]  # fmt: skip
    for entry in entries:
        assert entry["checkpoint"] == "untrained:smoke" and (entry["train_scenes"], entry["heldout_scenes"]) == (10, 4)
        assert entry["heldout_median_cm"] >= 0 and entry["constant_median_cm"] > 0
        assert (entry["initial_views"], entry["encoder_init"]) == ("fixed", "he")  # the smoke preset's
        assert ("heldout_refined_cm" in entry) == (entry["label"] in probe.MAP_LABELS)
    run(args)  # again, from the cached scenes: the same entries replace the old ones
    assert len(json.loads(path.read_text())) == 6
    with pytest.raises(ConfigError, match="have only nearest_object_xy, nearest_object_map, object_map"):
        run(ProbeArgs(source="untrained:smoke", labels=("target_xy",), out=tmp_path / "out", cache=tmp_path / "c"))


def test_the_gqn_measure_gives_the_mean_image_the_views_variance() -> None:
    """View 2 black in two scenes and white in two: the mean image is grey, its squared error 0.25 per value."""
    images = np.zeros((4, 3, 64, 64, 3), np.uint8)
    images[1::2, 2] = 255
    observations = {"images": images, "viewpoints": np.zeros((4, 3, 6), np.float32),
                    "gripper": np.zeros((4, 9), np.float32)}  # fmt: skip
    measure = APRAgent(ModelConfig.tiny(image_channels=3, grasp_action_dim=4)).gqn_measure(observations)
    assert measure["mean_image_mse"] == pytest.approx(0.25) and measure["views"] == 4
    assert 0.0 <= measure["prediction_mse"] <= 1.0 and 0.0 <= measure["reconstruction_mse"] <= 1.0
    assert measure["kl"] >= 0.0
    no_generator = APRAgent(ModelConfig.tiny(image_channels=3, grasp_action_dim=4, representation=False))
    assert no_generator.gqn_measure(observations) == {}


def test_the_spatial_readout_finds_a_one_hot_feature_at_its_cell() -> None:
    features = torch.zeros(1, 2, 16, 16)
    features[0, 0, 3, 10] = 50.0  # row 3, column 10
    features[0, 1, 15, 0] = 50.0  # the last row, the first column
    step = 2.0 / 15
    expected = torch.tensor([[-1 + 10 * step, -1 + 3 * step, -1.0, 1.0]])
    torch.testing.assert_close(SpatialSoftArgmax()(features), expected, atol=1e-4, rtol=0)
    assert Readout(16, (16, 8, 8), 16, 3, spatial=True)(torch.zeros(5, 16, 16, 16)).shape == (5, 3)


def test_the_object_map_peaks_at_each_object_and_a_look_is_scored_by_the_nearest_one() -> None:
    points = probe.map_points()
    objects = points[[5, 77]] + np.array([0.001, 0.0])  # two objects 1 mm beside two of the map's points
    values = probe.object_map(objects)
    assert values.shape == (probe.MAP_GRID**2,) and values[5] == pytest.approx(1 - 0.001 / probe.MAP_RADIUS)
    assert values[77] == pytest.approx(values[5]) and values.min() == 0.0
    padded = np.full((2, 8, 2), np.nan, np.float32)
    padded[:, :2] = objects
    looks = torch.zeros(2, probe.MAP_GRID**2)
    looks[0, 77] = 1.0  # looks at the second object: 0.1 cm
    far = int(np.linalg.norm(points[:, None] - objects, axis=-1).min(1).argmax())
    looks[1, far] = 1.0
    farthest_cm = 100 * np.linalg.norm(points[far] - objects, axis=1).min()
    assert probe.look_error_cm(looks, padded) == pytest.approx((0.1 + farthest_cm) / 2, abs=0.01)


def test_the_nearest_object_map_peaks_at_that_object_alone_and_is_scored_against_it() -> None:
    """Two objects beside two of the map's points; the one at point 77 is the nearest to the bin centre. A look at the
    other object scores 0 against every object (``object_map``) and their distance against the nearest alone."""
    points = probe.map_points()
    objects = points[[5, 77]].astype(np.float32)
    labels = {"nearest_object_xy": objects[None, 1]}
    object_xy = np.concatenate([objects, np.full((6, 2), np.nan)])[None]
    scenes = probe.Scenes(
        np.zeros((1, 3, 64, 64, 3), np.uint8),
        np.zeros((1, 3, 6), np.float32),
        np.zeros((1, 9), np.float32),
        labels,
        object_xy,
    )
    nearest_map = scenes.labels["nearest_object_map"]
    assert nearest_map.shape == (1, probe.MAP_GRID**2) and nearest_map[0].argmax() == 77 and nearest_map[0, 5] == 0.0
    look_at_the_other = torch.zeros(1, probe.MAP_GRID**2)
    look_at_the_other[0, 5] = 1.0
    between_cm = 100 * float(np.linalg.norm(objects[0] - objects[1]))
    assert probe.error_cm("object_map", look_at_the_other, None, scenes) == 0.0
    assert probe.error_cm("nearest_object_map", look_at_the_other, None, scenes) == pytest.approx(between_cm, abs=0.01)


def test_a_refined_look_finds_an_object_between_the_lattice_points() -> None:
    """An object midway between four lattice points: the map's lattice peak is half a cell's diagonal away (about
    2 cm), the peak refined within its cell (as the map critic reads its best point) nearer."""
    lattice = probe.map_points().reshape(probe.MAP_GRID, probe.MAP_GRID, 2)
    between = (0.5 * (lattice[5, 6] + lattice[6, 7]))[None]  # (1, 2)
    maps = torch.from_numpy(probe.object_map(between)[None]).float()
    object_xy = between[None].astype(np.float32)  # (1, 1, 2)
    lattice_cm, refined_cm = (probe.look_error_cm(maps, object_xy, refined) for refined in (False, True))
    half_diagonal_cm = 50 * np.linalg.norm(lattice[6, 7] - lattice[5, 6])
    assert lattice_cm == pytest.approx(half_diagonal_cm, abs=0.01)
    assert refined_cm < 0.5 * lattice_cm
    on_a_point = torch.from_numpy(probe.object_map(lattice[3, 4][None])[None]).float()  # at a lattice point: kept
    np.testing.assert_allclose(probe.map_peaks(on_a_point, refined=True), lattice[3, 4][None], atol=1e-9)


def test_scenes_survive_a_file_and_slicing_and_joining_derive_their_map_again(tmp_path) -> None:
    rng = np.random.default_rng(0)
    count = 4
    nearest = rng.uniform(-0.1, 0.1, (count, 2)).astype(np.float32)
    scenes = probe.Scenes(rng.integers(0, 255, (count, 3, 64, 64, 3), dtype=np.uint8),
                          rng.normal(size=(count, 3, 6)).astype(np.float32),
                          rng.normal(size=(count, 9)).astype(np.float32),
                          {"nearest_object_xy": nearest},
                          rng.normal(size=(count, probe.MAX_OBJECTS, 2)).astype(np.float32))  # fmt: skip
    probe.save_scenes(scenes, tmp_path / "scenes.npz")
    loaded = probe.load_scenes(tmp_path / "scenes.npz")
    joined = probe.Scenes.concatenate([loaded.take(slice(0, 1)), loaded.take(slice(1, None))])
    for copy in (loaded, joined):
        assert len(copy) == count
        np.testing.assert_array_equal(copy.images, scenes.images)
        np.testing.assert_array_equal(copy.object_xy, scenes.object_xy)
        for name in ("nearest_object_xy", "nearest_object_map"):
            np.testing.assert_array_equal(copy.labels[name], scenes.labels[name])
    np.testing.assert_array_equal(loaded.take(slice(2)).labels["nearest_object_map"],
                                  scenes.labels["nearest_object_map"][:2])  # fmt: skip
    (tmp_path / "damaged.npz").write_bytes(b"not a file of scenes")
    with pytest.raises((OSError, ValueError)):
        probe.load_scenes(tmp_path / "damaged.npz")
