"""``apr figures RUN_DIR``: the paper's pictures, made with a run's policy, each captioned with what made it.

1. ``fig1_logpolar.png``: a raw 256x256 head view beside its log-polar 64x64 sample (Figure 1 G/H).
2. ``fig3_active_vs_passive.png``: the model inputs over a 5-step episode, active (top) and passive (bottom),
   the same seed and the same gripper actions in both (Figure 3).
3. ``fig5_pregrasp.png``: close-ups of the gripper as each grasp starts, over several evaluation episodes
   (Figure 5: pre-grasp orientations).
4. ``fig6_gqn_predictions.png``: the generator's prediction of a view from the two others beside the truth, at
   the run's start and at each checkpoint it kept (Figure 6). The "w/o representation" ablation has no
   generator: skipped, with a note.
5. ``episodes.gif``: evaluation episodes (held-out objects, deterministic action) as the policy saw them.

Every title names the policy (the run and its grasps, a packaged checkpoint, an untrained agent, or the
scripted reach-and-grasp) and ``figures.md`` repeats the captions.
"""

from __future__ import annotations

import dataclasses
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from PIL import Image, ImageDraw, ImageFont

from apr.commands import checks
from apr.envs.config import VERSIONS
from apr.foveation import foveate
from apr.reproduce.episodes import (
    ActionSource,
    EpisodeRecord,
    GraspStart,
    agent_actions,
    make_env,
    replayed_actions,
    rgb,
    run_episode,
    scripted_actions,
    upscale,
)
from apr.reproduce.policies import (
    PolicySnapshot,
    initial_snapshot,
    load_run,
    load_training_checkpoint,
    picture_renderer,
    run_checkpoints,
)
from apr.train.checkpoints import CheckpointError, read_checkpoint
from apr.train.config import EnvConfig, is_passive, model_env_id
from apr.train.evaluation import EVAL_SEED
from apr.train.rollout import stack

SCRIPTED_LABEL = "the scripted reach-and-grasp (it reads the simulator's state; no learning)"
TITLE_CHARS_PER_INCH = 15
"""Characters per line of a figure title, per inch of figure width (8-point type)."""


@dataclass
class FiguresArgs:
    """Make the paper's pictures (Figures 1 G/H, 3, 5, 6 and a GIF) with a run's policy."""

    run_dir: Annotated[Path, tyro.conf.Positional]
    """A run folder (its latest checkpoint drives the episodes; Figure 6 uses every checkpoint it kept)."""
    out: Path = Path("figures")
    """Folder for the pictures and figures.md (created if missing)."""
    episodes: int = 3
    """Evaluation episodes for the GIF and Figure 5 (held-out objects, seeds as in apr eval)."""
    gif_episodes: int | None = None
    """Episodes in the GIF (the first ones); default: all of them."""
    steps: int = 5
    """Steps of the Figure 3 episode."""
    renderer: Literal["trained", "auto", "egl", "tiny"] = "trained"
    """trained: the renderer the run's policy was trained with (where it cannot serve, the one that can, with a
    warning); auto, egl or tiny: that one (a warning when it is not the policy's)."""


@dataclass
class FigureSet:
    """What ``make_figures`` wrote."""

    paths: dict[str, Path] = field(default_factory=dict)
    captions: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    """Pictures skipped, and why."""
    episodes: list[EpisodeRecord] = field(default_factory=list)
    """The evaluation episodes behind the GIF and Figure 5."""


# --------------------------------------------------------------------------------------------------- helpers
def _title(figure: Figure, text: str) -> tuple[Figure, str]:
    """Give ``figure`` its title; return both (the title doubles as the caption in figures.md)."""
    width = max(int(figure.get_figwidth() * TITLE_CHARS_PER_INCH), 40)
    figure.suptitle(textwrap.fill(text, width), fontsize=8)
    return figure, text


def _show(axes: Axes, image: np.ndarray, title: str = "") -> None:
    axes.imshow(image, interpolation="nearest")
    axes.set_xticks([])
    axes.set_yticks([])
    if title:
        axes.set_title(title, fontsize=7)


def _save(figure: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    return path


# ------------------------------------------------------------------------------------------------ Figure 1
def logpolar_figure(raw_view: np.ndarray, provenance: str) -> tuple[Figure, str]:
    """The raw view (256x256 at the paper's render size) beside its log-polar 64x64 sample (and the target mask,
    when it has one)."""
    sample = foveate(raw_view, "logpolar", 64)
    with_mask = raw_view.shape[-1] == 4
    figure = Figure(layout="constrained", figsize=(6.4, 6.4 if with_mask else 3.6))
    grid = figure.subplots(2 if with_mask else 1, 2, squeeze=False)
    _show(grid[0, 0], rgb(raw_view), f"raw view {raw_view.shape[0]}x{raw_view.shape[1]}")
    _show(grid[0, 1], rgb(sample), f"log-polar sample {sample.shape[0]}x{sample.shape[1]}")
    if with_mask:
        _show(grid[1, 0], raw_view[..., 3], "target mask (raw)")
        _show(grid[1, 1], sample[..., 3], "target mask (log-polar)")
        for axes in grid[1]:
            axes.images[0].set_cmap("gray")
    return _title(figure, f"Fig. 1 G/H: a head view before and after the log-polar-like warp. {provenance}")


# ------------------------------------------------------------------------------------------------ Figure 3
def active_vs_passive_figure(
    active: EpisodeRecord, passive: EpisodeRecord, driver: str, steps: int = 5
) -> tuple[Figure, str]:
    """Top: the active model's input (view 0 of 3, around the target); bottom: the passive model's (camera 0)."""
    columns = min(steps, len(active.frames), len(passive.frames))
    figure = Figure(layout="constrained", figsize=(1.6 * columns + 0.6, 4.0))
    grid = figure.subplots(2, columns, squeeze=False)
    for column in range(columns):
        _show(grid[0, column], rgb(active.frames[column].observation["images"][0]), f"t={column}")
        _show(grid[1, column], rgb(passive.frames[column].observation["images"][0]), f"t={column}")
    grid[0, 0].set_ylabel("active", fontsize=8)
    grid[1, 0].set_ylabel("passive", fontsize=8)
    return _title(
        figure,
        f"Fig. 3: model inputs (64x64) over one episode, seed {active.seed}, held-out objects. Top: "
        "active, view 0 of 3 around the target; bottom: passive, static camera 0 of 3. The gripper is "
        f"driven by {driver}; the same actions are replayed in both environments.",
    )


# ------------------------------------------------------------------------------------------------ Figure 5
def pregrasp_figure(records: Sequence[EpisodeRecord], policy_label: str, dof: int) -> tuple[Figure, str]:
    """Close-ups of the gripper as each grasp starts (or where an episode without a grasp stopped)."""
    shown = [(record, record.grasp_start or record.final_pose) for record in records]
    shown = [(record, pose) for record, pose in shown if pose is not None]
    columns = max(len(shown), 1)
    figure = Figure(layout="constrained", figsize=(max(2.4 * columns + 0.4, 5.0), 5.4))
    grid = figure.subplots(2, columns, squeeze=False)
    for column, (record, pose) in enumerate(shown):
        assert isinstance(pose, GraspStart)
        a, b, c = pose.euler_degrees
        moment = "grasp start" if record.grasp_start is not None else "no grasp: final pose"
        title = f"seed {record.seed}\n{moment}\na={round(a)}° b={round(b)}° c={round(c)}°\n{record.outcome}"
        for row, (name, view) in enumerate(pose.views.items()):
            _show(grid[row, column], view, title if row == 0 else "")
            if column == 0:
                grid[row, column].set_ylabel(name, fontsize=8)
    if not shown:
        grid[0, 0].text(0.5, 0.5, "no episode", ha="center")
    orientation = "6-DoF: b and c tilt the gripper" if dof == 6 else "4-DoF: the gripper points down (b = c = 0)"
    started = sum(record.grasp_start is not None for record in records)
    return _title(
        figure,
        f"Fig. 5: the gripper at the moment a grasp starts ({started} of {len(records)} episodes "
        f"started one), close-ups from behind and the side. Policy: {policy_label}, deterministic "
        f"action, held-out objects; {orientation}.",
    )


# ------------------------------------------------------------------------------------------------ Figure 6
def gqn_figure(
    snapshots: Sequence[PolicySnapshot], observations: Sequence[dict], run_label: str, query_view: int = 2
) -> tuple[Figure, str] | None:
    """Per scene: the two context views, the true query view, and each snapshot's prediction of it.

    Returns None when no snapshot has a generator (the "w/o representation" ablation).
    """
    with_generator = [snapshot for snapshot in snapshots if snapshot.agent.generator is not None]
    if not with_generator or not observations:
        return None
    context = [view for view in range(3) if view != query_view]
    columns = 3 + len(with_generator)
    figure = Figure(layout="constrained", figsize=(1.5 * columns + 0.4, 1.7 * len(observations) + 1.0))
    grid = figure.subplots(len(observations), columns, squeeze=False)
    predictions = [snapshot.agent.predict_view(stack(observations), query_view) for snapshot in with_generator]
    for row, observation in enumerate(observations):
        images = observation["images"]
        labels = [f"context view {context[0]}", f"context view {context[1]}", f"truth: view {query_view}"]
        for column, image in enumerate([images[context[0]], images[context[1]], images[query_view]]):
            _show(grid[row, column], rgb(image), labels[column] if row == 0 else "")
        for offset, (snapshot, predicted) in enumerate(zip(with_generator, predictions, strict=True)):
            image = (np.clip(predicted[row][..., :3], 0.0, 1.0) * 255).astype(np.uint8)
            _show(grid[row, 3 + offset], image, f"predicted\n{snapshot.grasps:,} grasps" if row == 0 else "")
    return _title(
        figure,
        f"Fig. 6: the generator's prediction of view {query_view} from views {context[0]} and "
        f"{context[1]} (a sample from the prior; RGB shown), at snapshots of {run_label}.",
    )


# ------------------------------------------------------------------------------------------------------ GIF
def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # an old Pillow, or no FreeType
        return ImageFont.load_default()


def episode_frames(records: Sequence[EpisodeRecord], policy_label: str, hold: int = 3) -> list[np.ndarray]:
    """GIF frames: a caption band over the raw view 0 (shown at 256x256) and the policy's three 64x64 inputs (x2), with
    the target mask of view 0 in the fourth cell when the inputs carry one."""
    font = _font(11)
    frames = []
    for number, record in enumerate(records, start=1):
        for index, frame in enumerate(record.frames):
            last = index == len(record.frames) - 1
            views = frame.observation["images"]
            inputs = [upscale(rgb(view), 128) for view in views]
            fourth = np.full_like(inputs[0], 255)  # the target mask of view 0, when the inputs have one
            if views.shape[-1] == 4:
                fourth = np.repeat(upscale(views[0][..., 3:], 128), 3, axis=-1)
            grid = np.concatenate([np.concatenate(inputs[:2], axis=1), np.concatenate([inputs[2], fourth], axis=1)])
            picture = np.concatenate([upscale(rgb(frame.raw_views[0]), grid.shape[0]), grid], axis=1)
            status = record.outcome if last else f"{frame.phase}, grasp step {frame.grasp_steps}"
            caption = [
                textwrap.shorten(policy_label, 92),
                f"episode {number}/{len(records)} (seed {record.seed}, held-out objects): {status}",
            ]
            band = Image.new("RGB", (picture.shape[1], 34), "white")
            draw = ImageDraw.Draw(band)
            for line, text in enumerate(caption):
                draw.text((4, 3 + 15 * line), text, fill="black", font=font)
            image = np.concatenate([np.asarray(band), picture])
            frames.extend([image] * (hold if last else 1))
    return frames


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: float = 3.0, colors: int = 128) -> Path:
    """An animated GIF, looping, with one palette of ``colors`` for all frames (computed from a sample of them)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(frame) for frame in frames]
    sample = np.concatenate([np.asarray(frames[k]) for k in np.linspace(0, len(frames) - 1, 8).astype(int)])
    palette = Image.fromarray(sample).quantize(colors=colors, method=Image.Quantize.MEDIANCUT)
    quantized = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    quantized[0].save(path, save_all=True, append_images=quantized[1:], duration=int(1000 / fps), loop=0, optimize=True)
    return path


# -------------------------------------------------------------------------------------------------- drivers
def _passive_counterpart(env_id: str) -> str:
    """The passive environment Figure 3 sets beside ``env_id``'s: of the same version, or of the newest version whose
    task is that version's (an active run on ``-v2`` is shown beside ``-v4``'s cameras framed on the tray: the active
    task of the two is the same)."""
    version = env_id.rpartition("-")[2]
    if is_passive(env_id):  # a passive policy's own cameras
        return env_id
    same_task = [name for name, kwargs in VERSIONS.items() if kwargs == VERSIONS.get(version)]
    return model_env_id(f"{env_id.rpartition('-')[0]}-{max(same_task, key=lambda v: int(v[1:]), default=version)}",
                        passive=True)  # fmt: skip


def fig3_driver(snapshot: PolicySnapshot) -> tuple[EnvConfig, EnvConfig, ActionSource | None, str]:
    """Which environment drives the Figure 3 episode, which one replays its actions, and with what policy.

    A run with environment-selected targets drives with its own policy in its own environment; a run that
    learns its fixation has no passive counterpart, so the scripted policy drives the active environment.

    Returns:
        (driving env, replaying env, policy or None for the scripted one, label of the policy).
    """
    env = snapshot.config.env  # each variant keeps the run's dof, renderer, render size, reveal_target, reach scale
    active = dataclasses.replace(env, env_id=model_env_id(env.env_id, passive=False), target="env",
                                 foveation="logpolar")  # fmt: skip
    passive = dataclasses.replace(env, env_id=_passive_counterpart(env.env_id), target="env", foveation="resize")
    if env.learned_fixation:
        return active, passive, None, SCRIPTED_LABEL
    policy = agent_actions(snapshot.agent)
    if is_passive(env.env_id):
        return passive, active, policy, f"the policy of {snapshot.label} (acting on the passive inputs)"
    own = dataclasses.replace(active, foveation=env.foveation)
    return own, passive, policy, f"the policy of {snapshot.label} (acting on the active inputs)"


def _episode(
    env_config: EnvConfig, policy: ActionSource, seed: int, renderer: str | None, max_grasp_steps: int | None = None
) -> EpisodeRecord:
    env = make_env(env_config, "test", renderer)
    try:
        return run_episode(env, policy, seed, max_grasp_steps)
    finally:
        env.close()


def evaluation_episodes(
    snapshot: PolicySnapshot, episodes: int, renderer: str | None = None, keep_frames: int | None = None
) -> list[EpisodeRecord]:
    """``episodes`` episodes of the policy on held-out objects, with the seeds and the deterministic action of
    ``apr eval``.

    Args:
        keep_frames: keep the frames of only the first this many episodes (None: all); the others keep their
            outcome and gripper close-ups.
    """
    env = make_env(snapshot.config.env, "test", renderer)
    policy = agent_actions(snapshot.agent)
    records = []
    try:
        for k in range(episodes):
            record = run_episode(env, policy, EVAL_SEED + k)
            if keep_frames is not None and k >= keep_frames:
                record.frames = []
            records.append(record)
    finally:
        env.close()
    return records


# ---------------------------------------------------------------------------------------------- all of them
def make_figures(
    snapshot: PolicySnapshot,
    out: Path,
    records: Sequence[EpisodeRecord],
    steps: int = 5,
    gqn_snapshots: Sequence[PolicySnapshot] | None = None,
    gqn_label: str = "",
    renderer: str | None = None,
    gif_episodes: int = 3,
    pregrasp_episodes: int = 6,
    renderer_note: str = "",
) -> FigureSet:
    """Write the five pictures of ``snapshot`` into ``out``, and their captions into ``out/figures.md``.

    Args:
        records: evaluation episodes run with ``snapshot`` (:func:`evaluation_episodes`): the first
            ``gif_episodes`` make the GIF, the first ``pregrasp_episodes`` Figure 5, the first 3 Figure 6's scenes.
        gqn_snapshots: the snapshots Figure 6 compares (default: ``snapshot`` alone), described by ``gqn_label``.
        renderer_note: why the episodes' images are not the kind the policy was trained on (a note of
            ``figures.md``; "" when they are).
    """
    result = FigureSet(episodes=list(records))
    if renderer_note:
        result.notes.append(f"Other images than in training: {renderer_note}.")
    label = snapshot.label
    shown = [record for record in records[:gif_episodes] if record.frames]

    def keep(name: str, captioned: tuple[Figure, str], filename: str) -> None:
        figure, caption = captioned
        result.paths[name] = _save(figure, out / filename)
        result.captions[name] = caption

    if shown:
        result.paths["gif"] = write_gif(out / "episodes.gif", episode_frames(shown, label))
        result.captions["gif"] = (
            f"{len(shown)} evaluation episode{'s' if len(shown) != 1 else ''} on held-out objects (deterministic "
            f"action): raw view 0 and the three 64x64 inputs. Policy: {label}."
        )
    else:
        result.notes.append("GIF skipped: no episode with its frames kept.")
    keep("fig5", pregrasp_figure(records[:pregrasp_episodes], label, snapshot.config.env.dof), "fig5_pregrasp.png")

    driving, replaying, policy, driver_label = fig3_driver(snapshot)
    driven = _episode(driving, policy or scripted_actions, EVAL_SEED, renderer, max_grasp_steps=steps)
    replayed = _episode(
        replaying,
        replayed_actions(driven.grasp_actions),
        EVAL_SEED,
        renderer,
        max_grasp_steps=len(driven.grasp_actions),
    )
    active, passive = (driven, replayed) if not is_passive(driving.env_id) else (replayed, driven)
    keep("fig3", active_vs_passive_figure(active, passive, driver_label, steps), "fig3_active_vs_passive.png")

    provenance = (
        f"View 0 at the start of the Figure 3 episode (seed {active.seed}, held-out objects, the "
        "environment's target fixated); no policy has acted yet."
    )
    keep("fig1", logpolar_figure(active.frames[0].raw_views[0], provenance), "fig1_logpolar.png")

    observations = [_scene_observation(record) for record in records[:3] if record.frames]
    captioned = gqn_figure(gqn_snapshots or [snapshot], observations, gqn_label or label)
    if captioned is None:
        why = (
            "no recorded observation"
            if observations
            else "this model has no generator (the 'w/o representation' ablation)"
        )
        result.notes.append(f"Fig. 6 skipped: {why}.")
    else:
        keep("fig6", captioned, "fig6_gqn_predictions.png")
    _write_captions(result, out, label)
    return result


def _scene_observation(record: EpisodeRecord) -> dict:
    """The first observation of the grasp phase (views around the target or the chosen fixation point)."""
    grasp_phase = [frame for frame in record.frames if frame.phase != "start"]
    return (grasp_phase or record.frames)[0].observation


PICTURE_ORDER = ("fig1", "fig3", "fig5", "fig6", "gif")
"""The order pictures are listed in (the paper's)."""


def ordered_pictures(result: FigureSet) -> list[tuple[str, Path]]:
    """(name, path) of the pictures written, in the paper's order."""
    return [(name, result.paths[name]) for name in PICTURE_ORDER if name in result.paths]


def _read_or_report(checkpoint: Path) -> dict | None:
    """A checkpoint's state; None for a damaged one, which is reported and left out of Figure 6."""
    try:
        return read_checkpoint(checkpoint)
    except CheckpointError as error:
        print(f"Figure 6 leaves out {error}")
        return None


def _write_captions(result: FigureSet, out: Path, label: str) -> None:
    lines = ["# Figures", "", f"Policy: {label}.", ""]
    for name, path in ordered_pictures(result):
        lines += [f"## {path.name}", "", f"![{name}]({path.name})", "", result.captions[name], ""]
    lines += [f"- {note}" for note in result.notes]
    (out / "figures.md").write_text("\n".join(lines) + "\n")


def run(args: FiguresArgs) -> FigureSet:
    checks.refuse("apr figures", [
        checks.at_least("--episodes", args.episodes, 1), checks.at_least("--steps", args.steps, 1),
        checks.at_least("--gif-episodes", args.gif_episodes, 0) if args.gif_episodes is not None else None,
        checks.output_folder("--out", args.out),
        None if args.run_dir.is_dir() else f"{args.run_dir} is not a run folder",
    ])  # fmt: skip
    snapshot = load_run(args.run_dir)
    snapshots = [initial_snapshot(snapshot.config, args.run_dir.name)]
    states = {path: _read_or_report(path) for path in run_checkpoints(args.run_dir)}
    snapshots += [load_training_checkpoint(path, state) for path, state in states.items() if state is not None]
    renderer, renderer_warning = picture_renderer(snapshot, args.renderer, "apr figures")
    if renderer_warning:
        print(textwrap.fill(f"warning: {renderer_warning}", 100))
    gqn_label = f"run {args.run_dir.name} (its initial weights, then each checkpoint it kept)"
    records = evaluation_episodes(snapshot, args.episodes, renderer)
    result = make_figures(
        snapshot,
        args.out,
        records,
        args.steps,
        snapshots,
        gqn_label,
        renderer,
        gif_episodes=args.gif_episodes or args.episodes,
        pregrasp_episodes=args.episodes,
        renderer_note=renderer_warning,
    )
    for name, path in result.paths.items():
        print(f"{name}: {path}")
    for note in result.notes:
        print(note)
    print(f"captions: {args.out / 'figures.md'}")
    return result
