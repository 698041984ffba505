"""What a representation knows: readouts fitted on the frozen r of an encoder (the linear-probe evaluation).

``apr probe SOURCE`` encodes the first views of training-split and held-out scenes (r = r1 + r2 of views 0 and 1, as
the policies see them), fits small readouts on r to labels the simulator gives, and reports their held-out median
errors in cm beside the constant predictor (the training labels' mean) and an upper bound: the same encoder
architecture and head, fresh, trained end to end on the same labels from the images. A probe may read the
simulator; a policy may not. Where localisation is lost shows in the gaps: constant to linear (what r holds in
plain sight), linear to head (what a head the size of the policy's can read), head to end to end (what the views
and the architecture allow that this encoder's training did not learn).

Labels (m):
- ``nearest_object_xy``: the xy of the object nearest the bin centre (every kind of scene).
- ``target_xy``: the xy of the environment's target (environment-target scenes, whose views fixate it).
- ``tip_target_offset``: the tool tip's offset from the target, xyz, after a few random grasp steps
  (environment-target scenes): what a grasp policy needs.
- ``object_map``: every object at once, as a map over the drop area: at each of ``MAP_GRID`` x ``MAP_GRID`` points,
  ``1 - min(d, MAP_RADIUS) / MAP_RADIUS``, d the xy distance to the nearest object centre (every kind of scene). Its
  error is that of a look: the xy distance from the predicted map's highest point to the nearest object, the
  question a learned fixation answers (the constant: the training maps' mean, whose highest point is one place).
- ``nearest_object_map``: ``nearest_object_xy`` as a map, the object nearest the bin centre alone (the same values
  around that one object, 0 elsewhere): heatmap rather than coordinate regression, as keypoint detectors read a
  location (Tompson et al. 2014, "Joint Training of a Convolutional Network and a Graphical Model for Human Pose
  Estimation"). A regression of the xy is pulled to the mean of the places the nearest object might be; a map can
  keep them apart and its highest point picks one. Its error: from that point to the nearest object, no other.
  Derived from ``nearest_object_xy`` (every kind of scene, cached scenes included).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import gymnasium as gym
import numpy as np
import torch
import tyro
from torch import nn
from tqdm import tqdm

import apr  # noqa: F401  (registers the environments)
from apr.envs.config import OBJECTS, SCENE
from apr.model.agent import APRAgent, Observation
from apr.model.config import ModelConfig
from apr.model.encoder import TowerEncoder, encode_scene, images_to_float
from apr.model.heads import SpatialSoftArgmax, conv_block, refined_peak
from apr.reproduce.policies import initial_snapshot, load_policy, untrained_snapshot
from apr.train.config import ConfigError, EnvConfig
from apr.train.trainer import Trainer

LABELS = ("nearest_object_xy", "nearest_object_map", "object_map", "target_xy", "tip_target_offset")
SCENE_LABELS = ("nearest_object_xy", "nearest_object_map", "object_map")
"""The labels of every kind of scene; the environment's target adds the rest."""
MAP_LABELS = ("nearest_object_map", "object_map")
"""The labels that are maps over the drop area: their error is that of a look at the map's highest point."""
DERIVED_LABELS = ("nearest_object_map",)
"""Labels :class:`Scenes` derives from the others when it is made: never written to the scene cache."""
READOUTS = ("linear", "head", "spatial", "end_to_end")
PROBE_SEED = 3_000_000_000
"""Probe scenes use the seeds PROBE_SEED + k (training split) and PROBE_SEED + HELDOUT_OFFSET + k (held out): apart
from the training runs' episodes and the evaluations' (EVAL_SEED + k), the same for every probed encoder."""
HELDOUT_OFFSET = 500_000
MAX_RANDOM_STEPS = 6
"""Environment-target scenes are taken after 0 to this many random grasp steps, so the tool tip varies."""
UNTRAINED_PREFIX = "untrained:"
INITIAL_PREFIX = "initial:"
MAP_GRID = 12
"""Points per side of ``object_map``: 2.8 cm apart over the drop area."""
MAP_RADIUS = 0.06
"""m: beyond this xy distance from every object centre a point of ``object_map`` is 0."""
MAX_OBJECTS = 8
"""Object centres kept per scene (NaN rows pad fewer): for the errors of ``object_map``."""


def map_points() -> np.ndarray:
    """The xy (m) of ``object_map``'s points, (MAP_GRID ** 2, 2), row by row, over the objects' drop area."""
    margin = 0.02
    x = np.linspace(OBJECTS.drop_x[0] - margin, sum(OBJECTS.drop_x) + margin, MAP_GRID)
    y = np.linspace(-OBJECTS.drop_y_width / 2 - margin, OBJECTS.drop_y_width / 2 + margin, MAP_GRID)
    return np.stack(np.meshgrid(x, y, indexing="ij"), -1).reshape(-1, 2)


def object_map(object_xy: np.ndarray) -> np.ndarray:
    """``object_map`` of one scene from its objects' xy (N, 2): (MAP_GRID ** 2,) in [0, 1]."""
    distance = np.linalg.norm(map_points()[:, None] - object_xy[None], axis=-1).min(axis=1)
    return 1.0 - np.minimum(distance, MAP_RADIUS) / MAP_RADIUS


@dataclass
class ProbeArgs:
    """What a representation knows: readouts on the frozen r of a run's encoder, against the constant predictor and
    an upper bound trained end to end; writes results/probe/NAME/probe.json."""

    source: Annotated[str, tyro.conf.Positional]
    """A run folder, a checkpoint file, ``untrained:PRESET`` (fresh weights of a preset) or ``initial:RUN`` (the run
    folder's weights before its first grasp: its seed's fresh weights, with the GQN it started from if any)."""
    name: str = ""
    """The folder under ``--out``; default: the run's folder name, ``untrained-PRESET`` or ``initial-RUN``."""
    out: Path = Path("results/probe")
    """Parent folder of the probes' folders."""
    train_scenes: int = 500
    """Training-split scenes the readouts are fitted on."""
    heldout_scenes: int = 100
    """Held-out scenes (the 100 test objects, exactly 5 in the tray) the errors are measured on."""
    labels: tuple[str, ...] = ()
    """Labels to probe (``nearest_object_xy``, ``nearest_object_map``, ``object_map``, ``target_xy``,
    ``tip_target_offset``); default: every one the scenes have."""
    readouts: tuple[str, ...] = READOUTS
    """``linear`` (ridge regression on r, its strength chosen by 5-fold cross-validation), ``head`` (a conv block
    the size of the policy heads' and a linear layer, on r), ``spatial`` (the same with spatial soft-argmax
    keypoints before the linear layer) and ``end_to_end`` (the upper bound)."""
    steps: int = 1500
    """Adam steps of the ``head`` and ``end_to_end`` readouts (batch 32)."""
    seed: int = 0
    """Seeds the readouts' initialisation and batches (the scenes have their own seeds)."""
    threads: int = 1
    """CPU threads for torch (small tensors: one is fastest, and far faster than two beside other work)."""
    initial_views: Literal["", "drawn", "fixed"] = ""
    """The head's views at reset in the probe's scenes (``--env.initial-views`` of training); default: the
    source's."""
    cache: Path = Path("runs/probe-scenes")
    """Rendered scenes are kept here (a few hundred MB at most), keyed by environment, split, count and seed."""


@dataclass
class Scenes:
    """Observations of scenes and their labels."""

    images: np.ndarray
    """uint8 (S, 3, 64, 64, C)."""
    viewpoints: np.ndarray
    """float32 (S, 3, 6)."""
    gripper: np.ndarray
    """float32 (S, 9)."""
    labels: dict[str, np.ndarray] = field(default_factory=dict)
    """Each float32 (S, D): metres, or the values of ``object_map``."""
    object_xy: np.ndarray | None = None
    """float32 (S, MAX_OBJECTS, 2): the objects' centres, NaN rows for fewer (the simulator's; for errors only)."""

    def __post_init__(self) -> None:
        if "nearest_object_xy" in self.labels:  # derived, so that scenes cached before it have it too
            self.labels["nearest_object_map"] = np.stack(
                [object_map(xy[None]) for xy in self.labels["nearest_object_xy"]]
            ).astype(np.float32)

    def observation(self, index: np.ndarray | slice = slice(None)) -> Observation:
        return Observation.from_env({"images": self.images[index], "viewpoints": self.viewpoints[index],
                                     "gripper": self.gripper[index]})  # fmt: skip

    def __len__(self) -> int:
        return len(self.images)

    def take(self, index: np.ndarray | slice) -> Scenes:
        """The scenes at ``index``, their derived labels derived again."""
        return Scenes(self.images[index], self.viewpoints[index], self.gripper[index],
                      {name: value[index] for name, value in self.labels.items() if name not in DERIVED_LABELS},
                      None if self.object_xy is None else self.object_xy[index])  # fmt: skip

    @staticmethod
    def concatenate(parts: list[Scenes]) -> Scenes:
        """The scenes of ``parts``, in order."""
        return Scenes(np.concatenate([part.images for part in parts]),
                      np.concatenate([part.viewpoints for part in parts]),
                      np.concatenate([part.gripper for part in parts]),
                      {name: np.concatenate([part.labels[name] for part in parts]) for name in parts[0].labels
                       if name not in DERIVED_LABELS},
                      np.concatenate([part.object_xy for part in parts]))  # fmt: skip


# ------------------------------------------------------------------------------------------------ scenes
def scene_labels(info: dict, target: str) -> dict[str, np.ndarray]:
    """The labels of one scene from the env's ``info`` (the simulator's view)."""
    centres = np.asarray(info["object_centres"], np.float64)
    nearest = centres[np.linalg.norm(centres[:, :2] - np.array(SCENE.bin_centre)[:2], axis=1).argmin()]
    labels = {"nearest_object_xy": nearest[:2], "object_map": object_map(centres[:, :2])}
    if target == "env":
        labels["target_xy"] = np.asarray(info["fixation_point"], np.float64)[:2]
        labels["tip_target_offset"] = np.asarray(info["tool_tip"], np.float64) - info["fixation_point"]
    return {name: value.astype(np.float32) for name, value in labels.items()}


def collect_scenes(env_config: EnvConfig, split: str, count: int, first_seed: int) -> Scenes:
    """``count`` scenes of ``split``: the reset views (a learned fixation's look at the bin centre) or, with the
    environment's target, the views after 0 to ``MAX_RANDOM_STEPS`` random grasp steps (mostly level; a scene
    whose steps started a grasp is passed over for the next seed). Every draw comes from the scene's seed."""
    env = gym.make(env_config.env_id, **env_config.make_kwargs(split))
    images, viewpoints, gripper, labels, object_xy = [], [], [], [], []
    seed = first_seed
    try:
        with tqdm(total=count, desc=f"probe scenes ({split})", unit="scene", leave=False) as bar:
            while len(images) < count:
                observation, info = env.reset(seed=seed)
                rng = np.random.default_rng(seed)
                seed += 1
                if env_config.target == "env":
                    observation, info = _random_steps(env, observation, info, rng, env_config.dof)
                    if observation is None:
                        continue
                images.append(observation["images"])
                viewpoints.append(observation["viewpoints"])
                gripper.append(observation["gripper"])
                labels.append(scene_labels(info, env_config.target))
                object_xy.append(padded_object_xy(info))
                bar.update()
    finally:
        env.close()
    return Scenes(np.stack(images), np.stack(viewpoints).astype(np.float32), np.stack(gripper).astype(np.float32),
                  {name: np.stack([scene[name] for scene in labels]) for name in labels[0]},
                  np.stack(object_xy))  # fmt: skip


def padded_object_xy(info: dict) -> np.ndarray:
    """The scene's object centres' xy, (MAX_OBJECTS, 2) float32, NaN rows where it has fewer."""
    centres = np.asarray(info["object_centres"], np.float32)[:MAX_OBJECTS, :2]
    return np.concatenate([centres, np.full((MAX_OBJECTS - len(centres), 2), np.nan, np.float32)])


def _random_steps(env, observation, info, rng: np.random.Generator, dof: int):
    for _ in range(int(rng.integers(0, MAX_RANDOM_STEPS + 1))):
        action = rng.uniform(-1.0, 1.0, dof).astype(np.float32)
        action[2] = rng.uniform(-0.6, 0.3)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:  # a grasp started: no scene to probe
            return None, None
    return observation, info


def save_scenes(scenes: Scenes, path: Path) -> None:
    """Write ``scenes`` to the ``.npz`` file ``path`` whole or not at all (through a temporary file); the derived
    labels are left out, :class:`Scenes` derives them again."""
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "wb") as file:
        np.savez(file, images=scenes.images, viewpoints=scenes.viewpoints, gripper=scenes.gripper,
                 object_xy=scenes.object_xy,
                 **{f"label_{name}": value for name, value in scenes.labels.items()
                    if name not in DERIVED_LABELS})  # fmt: skip
    temporary.replace(path)


def load_scenes(path: Path) -> Scenes:
    """The scenes :func:`save_scenes` wrote (``OSError``, ``ValueError`` or ``KeyError`` for a damaged file)."""
    with np.load(path) as data:
        return Scenes(data["images"], data["viewpoints"], data["gripper"],
                      {name.removeprefix("label_"): data[name] for name in data.files if name.startswith("label_")},
                      data["object_xy"])  # fmt: skip


def cached_scenes(env_config: EnvConfig, split: str, count: int, first_seed: int, cache: Path) -> Scenes:
    """:func:`collect_scenes`, kept in ``cache`` (an interrupted or damaged file is rendered again)."""
    key = json.dumps([dataclasses.asdict(env_config), split, count, first_seed], sort_keys=True)
    path = cache / f"{split}_{count}_{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"
    if path.exists():
        try:
            return load_scenes(path)
        except (OSError, ValueError, KeyError) as error:
            tqdm.write(f"{path} is unreadable ({error}): rendering its scenes again")
    scenes = collect_scenes(env_config, split, count, first_seed)
    cache.mkdir(parents=True, exist_ok=True)
    save_scenes(scenes, path)
    return scenes


# ---------------------------------------------------------------------------------------------- readouts
@torch.no_grad()
def encode(agent: APRAgent, scenes: Scenes, batch: int = 64) -> torch.Tensor:
    """r of views 0 and 1 of every scene, as the policies see it: (S, R, 16, 16), fp32, on the CPU."""
    parts = []
    for start in range(0, len(scenes), batch):
        observation = scenes.observation(slice(start, start + batch)).to(agent.device)
        parts.append(agent._scene(observation, agent._first_two(len(observation)), with_grad=0).float().cpu())
    return torch.cat(parts)


def fit_linear(features: torch.Tensor, labels: torch.Tensor, heldout: torch.Tensor, folds: int = 5) -> torch.Tensor:
    """Ridge regression of ``labels`` (N, D) on the flattened ``features`` (N, ...), its strength chosen by
    ``folds``-fold cross-validation on the training scenes; returns the predictions for ``heldout`` (M, D), on the
    features' device. The dual form (an N x N system) keeps it exact and cheap when features outnumber scenes."""
    x, x_heldout = features.flatten(1).double(), heldout.flatten(1).double()
    mean, scale = x.mean(0), x.std(0).clamp_min(1e-8)
    x, x_heldout = (x - mean) / scale, (x_heldout - mean) / scale
    y = labels.double()
    y_mean = y.mean(0)

    def solve(train_x: torch.Tensor, train_y: torch.Tensor, strength: float) -> torch.Tensor:
        gram = train_x @ train_x.T
        identity = torch.eye(len(gram), dtype=gram.dtype, device=gram.device)
        dual = torch.linalg.solve(gram + strength * identity, train_y - y_mean)
        return train_x.T @ dual  # (F, D)

    strengths = [x.shape[1] * factor for factor in (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)]
    fold = torch.arange(len(x), device=x.device) % folds
    errors = []
    for strength in strengths:
        error = 0.0
        for k in range(folds):
            weights = solve(x[fold != k], y[fold != k], strength)
            error += float(((x[fold == k] @ weights + y_mean - y[fold == k]) ** 2).sum())
        errors.append(error)
    weights = solve(x, y, strengths[int(np.argmin(errors))])
    return (x_heldout @ weights + y_mean).float()


class Readout(nn.Module):
    """A head the size of the policies': a conv block (3x3 kernels) and one linear layer, r -> (D,). ``spatial``:
    the conv block's maps become keypoints (:class:`SpatialSoftArgmax`) before the linear layer."""

    def __init__(self, channels_in: int, channels: tuple[int, ...], grid: int, out: int, spatial: bool = False):
        super().__init__()
        if spatial:
            self.trunk = nn.Sequential(*conv_block(channels_in, channels)[:-1], SpatialSoftArgmax())
            self.out = nn.Linear(2 * channels[-1], out)
        else:
            self.trunk = conv_block(channels_in, channels)
            self.out = nn.Linear(channels[-1] * grid * grid, out)

    def forward(self, r: torch.Tensor) -> torch.Tensor:
        return self.out(self.trunk(r))


def train_regressor(predict: Callable[[torch.Tensor], torch.Tensor], parameters: list[nn.Parameter],
                    inputs: int, labels: torch.Tensor, steps: int, seed: int, batch: int = 32) -> None:  # fmt: skip
    """Adam on the mean squared error of standardised ``labels`` (N, D), on their device; ``predict`` maps sample
    indices (B,) (on the CPU) to standardised predictions (B, D)."""
    generator = torch.Generator().manual_seed(seed)
    optimizer = torch.optim.Adam(parameters, lr=1e-3, weight_decay=1e-4)
    for _ in range(steps):
        index = torch.randint(inputs, (batch,), generator=generator)
        loss = ((predict(index) - labels[index.to(labels.device)]) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()


def fit_head(features: torch.Tensor, labels: torch.Tensor, heldout: torch.Tensor, channels: tuple[int, ...],
             steps: int, seed: int, spatial: bool = False) -> torch.Tensor:  # fmt: skip
    """A :class:`Readout` trained on frozen ``features`` (N, R, G, G); predictions for ``heldout`` (M, D)."""
    torch.manual_seed(seed)
    mean, scale = labels.mean(0), labels.std(0).clamp_min(1e-6)
    readout = Readout(features.shape[1], channels, features.shape[-1], labels.shape[1], spatial)
    train_regressor(lambda index: readout(features[index]), list(readout.parameters()), len(features),
                    (labels - mean) / scale, steps, seed)  # fmt: skip
    with torch.no_grad():
        return readout(heldout) * scale + mean


def fit_end_to_end(config: ModelConfig, train: Scenes, labels: torch.Tensor, heldout: Scenes, steps: int,
                   seed: int, device: torch.device | str = "cpu", batch: int = 32) -> torch.Tensor:  # fmt: skip
    """The upper bound: a fresh encoder of ``config``'s architecture and a :class:`Readout`, trained together on
    ``device`` from the images and poses of views 0 and 1 to ``labels``; predictions for ``heldout`` (M, D), on the
    CPU."""
    torch.manual_seed(seed)
    encoder = TowerEncoder(config.image_channels, config.pose_dim, config.encoder_channels,
                           config.encoder_narrow_channels, config.representation_channels,
                           config.encoder_init).to(device)  # fmt: skip
    readout = Readout(config.representation_channels, tuple(config.head_channels), config.image_size // 4,
                      labels.shape[1]).to(device)  # fmt: skip
    labels = labels.to(device)
    mean, scale = labels.mean(0), labels.std(0).clamp_min(1e-6)

    def predict(scenes: Scenes, index: torch.Tensor | slice) -> torch.Tensor:
        observation = scenes.observation(index if isinstance(index, slice) else index.numpy()).to(device)
        images = images_to_float(observation.images[:, :2]).contiguous()
        return readout(encode_scene(encoder, images, observation.poses()[:, :2]))

    parameters = [*encoder.parameters(), *readout.parameters()]
    train_regressor(lambda index: predict(train, index), parameters, len(train), (labels - mean) / scale, steps,
                    seed, batch)  # fmt: skip
    with torch.no_grad():
        parts = [predict(heldout, slice(start, start + 64)) for start in range(0, len(heldout), 64)]
        return (torch.cat(parts) * scale + mean).cpu()


def median_cm(predictions: torch.Tensor, labels: torch.Tensor) -> float:
    """Median Euclidean error over scenes, in cm."""
    return round(100 * float((predictions - labels).norm(dim=1).median()), 2)


def map_peaks(maps: torch.Tensor, refined: bool = False) -> np.ndarray:
    """The xy (m) of each predicted map's highest point, (M, 2), from maps (M, MAP_GRID ** 2): its lattice point, or
    with ``refined`` that point moved within its cell as the map critic reads its best point (:func:`refined_peak`)."""
    if not refined:
        return map_points()[maps.argmax(dim=1).numpy()]
    lattice = map_points().reshape(MAP_GRID, MAP_GRID, 2)
    step = lattice[1, 1] - lattice[0, 0]  # (dx, dy) between neighbouring points
    return lattice[0, 0] + refined_peak(maps.reshape(-1, MAP_GRID, MAP_GRID)).double().numpy() * step


def look_error_cm(maps: torch.Tensor, object_xy: np.ndarray, refined: bool = False) -> float:
    """The error of predicted maps (M, MAP_GRID ** 2): the median over scenes of the xy distance (cm) from each map's
    highest point (:func:`map_peaks`) to the nearest of its scene's objects (``object_xy``: (M, K, 2), NaN rows for
    none)."""
    looked = map_peaks(maps, refined)  # (M, 2)
    distance = np.linalg.norm(looked[:, None] - object_xy, axis=-1)  # (M, K), NaN for padding
    return round(100 * float(np.median(np.nanmin(distance, axis=1))), 2)


def error_cm(label: str, predictions: torch.Tensor, labels: torch.Tensor, scenes: Scenes,
             refined: bool = False) -> float:  # fmt: skip
    """A label's held-out error in cm: :func:`look_error_cm` for the maps (``object_map`` against every object,
    ``nearest_object_map`` against the nearest object alone; ``refined``: their peaks refined within the lattice
    cell), else :func:`median_cm`."""
    if label == "object_map":
        return look_error_cm(predictions, scenes.object_xy, refined)
    if label == "nearest_object_map":
        return look_error_cm(predictions, scenes.labels["nearest_object_xy"][:, None], refined)
    return median_cm(predictions, labels)


# ----------------------------------------------------------------------------------------------- the probe
def probe_entries(agent: APRAgent, train: Scenes, heldout: Scenes, checkpoint: str, labels: tuple[str, ...],
                  readouts: tuple[str, ...], steps: int, seed: int) -> list[dict]:  # fmt: skip
    """Every (label, readout) of the probe of ``agent``'s encoder: the entries of probe.json."""
    r_train, r_heldout = encode(agent, train), encode(agent, heldout)
    entries = []
    for label in labels:
        y_train, y_heldout = torch.from_numpy(train.labels[label]), torch.from_numpy(heldout.labels[label])
        constant = error_cm(label, y_train.mean(0).expand_as(y_heldout), y_heldout, heldout)
        for readout in readouts:
            tqdm.write(f"probe: {label}, {readout} readout")
            if readout == "linear":
                predicted = fit_linear(r_train, y_train, r_heldout)
            elif readout in ("head", "spatial"):
                predicted = fit_head(r_train, y_train, r_heldout, tuple(agent.config.head_channels), steps, seed,
                                     spatial=readout == "spatial")  # fmt: skip
            else:
                predicted = fit_end_to_end(agent.config, train, y_train, heldout, steps, seed)
            entry = {
                "checkpoint": checkpoint,
                "label": label,
                "readout": readout,
                "heldout_median_cm": error_cm(label, predicted, y_heldout, heldout),
                "constant_median_cm": constant,
                "train_scenes": len(train),
                "heldout_scenes": len(heldout),
            }
            if label in MAP_LABELS:  # the peak refined within its lattice cell, as the map critic reads its own
                entry["heldout_refined_cm"] = error_cm(label, predicted, y_heldout, heldout, refined=True)
            entries.append(entry)
    return entries


def entry_key(entry: dict) -> tuple:
    """What one probe.json entry measured; a new entry replaces an old one with the same key (entries written before
    ``initial_views`` and ``encoder_init`` were recorded had drawn views and PyTorch's default initialisation)."""
    names = ("checkpoint", "label", "readout", "train_scenes")
    return (*(entry.get(name) for name in names), entry.get("initial_views", "drawn"),
            entry.get("encoder_init", "torch"))  # fmt: skip


def problems(args: ProbeArgs) -> list[str]:
    """What makes the arguments unusable, one sentence each (empty: none)."""
    found = []
    for name in ("train_scenes", "heldout_scenes", "steps", "threads"):
        if getattr(args, name) < 1:
            found.append(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    found += [f"--labels: unknown label {label!r}; the labels are {', '.join(LABELS)}" for label in args.labels
              if label not in LABELS]  # fmt: skip
    found += [f"--readouts: unknown readout {readout!r}; the readouts are {', '.join(READOUTS)}"
              for readout in args.readouts if readout not in READOUTS]  # fmt: skip
    if not args.source.startswith(UNTRAINED_PREFIX) and not Path(args.source.removeprefix(INITIAL_PREFIX)).exists():
        found.append(f"{args.source} does not exist (a run folder, a checkpoint, untrained:PRESET or initial:RUN)")
    return found


def run(args: ProbeArgs) -> Path:
    """``apr probe``: probe the encoder of ``args.source``; write (or update) ``OUT/NAME/probe.json``."""
    found = problems(args)
    if found:
        raise ConfigError("\n".join(found))
    torch.set_num_threads(args.threads)
    if args.source.startswith(UNTRAINED_PREFIX):
        preset_name = args.source.removeprefix(UNTRAINED_PREFIX)
        try:
            snapshot = untrained_snapshot(preset_name)
        except ValueError as error:
            raise ConfigError(str(error)) from None
        name = args.name or f"untrained-{preset_name}"
    elif args.source.startswith(INITIAL_PREFIX):
        run_dir = Path(args.source.removeprefix(INITIAL_PREFIX))
        snapshot = initial_snapshot(Trainer.saved_config(run_dir), run_dir.name)  # config.json: no checkpoint needed
        name = args.name or f"initial-{run_dir.name}"
    else:
        snapshot = load_policy(Path(args.source))
        source = Path(args.source)
        name = args.name or (source.name if source.is_dir() else source.parent.parent.name)
    env = dataclasses.replace(snapshot.config.env, renderer="tiny")
    if args.initial_views:
        env = dataclasses.replace(env, initial_views=args.initial_views)
        if env.initial_views_problem:
            raise ConfigError(f"--initial-views {env.initial_views_problem}")
    available = LABELS if env.target == "env" else SCENE_LABELS
    labels = args.labels or available
    unavailable = [label for label in labels if label not in available]
    if unavailable:
        raise ConfigError(f"--labels {' '.join(unavailable)}: these scenes (target={env.target!r}) have only "
                          f"{', '.join(available)}")  # fmt: skip
    train = cached_scenes(env, "train", args.train_scenes, PROBE_SEED, args.cache)
    heldout = cached_scenes(env, "test", args.heldout_scenes, PROBE_SEED + HELDOUT_OFFSET, args.cache)
    entries = probe_entries(snapshot.agent, train, heldout, args.source, labels, args.readouts, args.steps,
                            args.seed)  # fmt: skip
    for entry in entries:
        entry["initial_views"] = env.initial_views
        entry["encoder_init"] = snapshot.config.model.encoder_init
    path = args.out / name / "probe.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    kept = []
    if path.exists():
        try:
            kept = json.loads(path.read_text())
        except (OSError, ValueError) as error:
            tqdm.write(f"{path} is unreadable ({error}): writing it anew")
    new_keys = {entry_key(entry) for entry in entries}
    kept = [entry for entry in kept if entry_key(entry) not in new_keys]
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(kept + entries, indent=2) + "\n")
    temporary.replace(path)
    for entry in entries:
        refined = f", {entry['heldout_refined_cm']:.2f} refined" if "heldout_refined_cm" in entry else ""
        print(f"{entry['label']:>18} {entry['readout']:>10}: {entry['heldout_median_cm']:6.2f} cm held out{refined} "
              f"(constant {entry['constant_median_cm']:.2f} cm)")  # fmt: skip
    print(f"wrote {path}")
    return path
