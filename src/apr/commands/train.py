"""``apr train``, ``apr eval`` and ``apr presets``."""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from apr.commands import backends, checks
from apr.model.config import ModelConfig
from apr.train.config import ACTIVE_ENV_ID, DERIVED_MODEL_FIELDS, PRESETS, TrainConfig, flag, is_passive, preset

PresetName = Literal[tuple(PRESETS)]  # type: ignore[valid-type]


@dataclass
class _CliModelConfig(ModelConfig):
    """Sizes, optimiser settings and speed options of the APR learner (paper values by default)."""

    image_channels: Annotated[int, tyro.conf.Suppress] = 3
    grasp_action_dim: Annotated[int, tyro.conf.Suppress] = 6
    seed: Annotated[int, tyro.conf.Suppress] = 0


@dataclass
class _CliTrainConfig(TrainConfig):
    """A training run of APR, without the model fields that follow from others (they are not options)."""

    model: _CliModelConfig = field(default_factory=_CliModelConfig)


@dataclass
class TrainArgs:
    """Train APR: ``apr train --preset NAME [--FIELD VALUE ...]`` or ``apr train --resume RUN_DIR``."""

    config: Annotated[_CliTrainConfig, tyro.conf.arg(name="")]
    preset: PresetName = "active-target"
    """The preset a new run starts from (apr presets describes them); the defaults below are its values."""
    resume: Annotated[Path | None, tyro.conf.arg(metavar="RUN_DIR")] = None
    """Continue the run in RUN_DIR from its newest intact checkpoint; the defaults below are then the run's."""


def _description(name: str | None, resuming: bool) -> str:
    presets = ", ".join(PRESETS)
    head = (
        "Continue a run: the defaults below are the run's own; budgets, schedules, processes and speed options "
        "may change, fields that shape its networks or replay may not."
        if resuming
        else f"Train APR from preset {name}: {PRESETS[name][0]}. Any field below overrides the preset."
    )
    return (
        f"{head} Presets (--preset NAME): {presets}. Continue a run: --resume RUN_DIR. Not options, because "
        "they follow from others: --model.image-channels (--env.target), --model.grasp-action-dim (--env.dof), "
        "--model.seed (--seed); --model.gqn-anneal-updates follows --total-grasps unless --no-anneal-over-run."
    )


def _given(argv: list[str], path: str) -> bool:
    """Whether ``argv`` sets the field ``path`` (``--a.b-c V``, ``--a.b_c=V``)."""
    return any(token.split("=", 1)[0].replace("_", "-") == flag(path) for token in argv)


def _to_cli(config: TrainConfig) -> _CliTrainConfig:
    model = _CliModelConfig(**{f.name: getattr(config.model, f.name) for f in dataclasses.fields(ModelConfig)})
    values = {f.name: getattr(config, f.name) for f in dataclasses.fields(TrainConfig) if f.name != "model"}
    return _CliTrainConfig(**values, model=model)


def _from_cli(config: TrainConfig) -> TrainConfig:
    model = ModelConfig(**{f.name: getattr(config.model, f.name) for f in dataclasses.fields(ModelConfig)})
    values = {f.name: getattr(config, f.name) for f in dataclasses.fields(TrainConfig) if f.name != "model"}
    return TrainConfig(**values, model=model)


def _contradicted(argv: list[str], config: TrainConfig) -> list[str]:
    """Flags given in ``argv`` that the rest of ``config`` makes meaningless. Only what the user gave counts: a
    passive run started from an active preset inherits its logpolar, which is no contradiction (the passive
    cameras are resized whatever it says, and the run records resize: ``TrainConfig.resolved``)."""
    found = []
    if _given(argv, "env.foveation") and config.env.foveation == "logpolar" and is_passive(config.env.env_id):
        found.append(f"--env.foveation logpolar contradicts --env.env-id {config.env.env_id}: the passive model's "
                     "static cameras are resized, with no log-polar warp; drop the flag, or use --env.env-id "
                     f"{ACTIVE_ENV_ID}")  # fmt: skip
    return found


def train(argv: list[str]) -> None:
    """``apr train --preset NAME [--field value ...]`` or ``apr train --resume RUN_DIR [--field value ...]``."""
    from apr.train.trainer import RunFinished, Trainer

    first = argparse.ArgumentParser(prog="apr train", add_help=False)
    first.add_argument("--preset", default=None)
    first.add_argument("--resume", type=Path, default=None)
    known, _ = first.parse_known_args(argv)
    derived = [f"{flag('model.' + name)} (it follows {source})" for name, source in DERIVED_MODEL_FIELDS.items()
               if _given(argv, f"model.{name}")]  # fmt: skip
    checks.refuse("apr train", [f"{', '.join(derived)}: not an option, set by the field it follows"] if derived else [])
    if known.resume is not None and known.preset is not None:
        checks.refuse("apr train", ["--preset starts a new run; a resumed run keeps the preset it started with"])
    name = known.preset if known.preset in PRESETS else "active-target"  # tyro reports an unknown preset
    default = Trainer.saved_config(known.resume) if known.resume is not None else preset(name)
    shown = default.preset if default.preset in PRESETS else name
    args = tyro.cli(TrainArgs, default=TrainArgs(config=_to_cli(default), preset=shown, resume=known.resume),
                    args=argv, prog="apr train", description=_description(name, known.resume is not None))  # fmt: skip
    config = _from_cli(args.config)
    if _given(argv, "model.gqn_anneal_updates") and config.anneal_over_run:
        checks.refuse("apr train", ["--model.gqn-anneal-updates is set from --total-grasps while --anneal-over-run "
                                    "is on; add --no-anneal-over-run to set it yourself"])  # fmt: skip
    checks.refuse("apr train", [*_contradicted(argv, config), *config.problems(),
                                *backends.workers_problems(config.backend)])  # fmt: skip
    workers = backends.workers_factory(config.backend, config.ray_address)
    try:
        if args.resume is not None:
            trainer = Trainer.resume(args.resume, config, workers=workers)
        else:
            trainer = Trainer(config, workers=workers)
    except RunFinished as finished:
        print(finished)
        return
    run_dir = trainer.train()
    print(f"run folder: {run_dir}")


@dataclass
class EvalArgs:
    """Evaluate a run's newest intact checkpoint, or a given checkpoint, on held-out objects."""

    path: Annotated[Path, tyro.conf.Positional]
    """A run folder (its newest intact checkpoint) or a checkpoint file (RUN/checkpoints/checkpoint_*.pt)."""
    episodes: int = 100
    """Episodes to run (SPEC: at least 100 per checkpoint)."""
    split: Literal["test", "train"] = "test"
    """Object split: the 100 held-out objects, or the 900 training ones."""
    json: Path | None = None
    """Write the result (rate, 95% interval, per-episode outcomes) to this JSON file."""
    workers: int = 0
    """Environment processes; 0 = the run's number of workers."""
    renderer: Literal["trained", "auto", "egl", "tiny"] = "trained"
    """trained: the renderer the checkpoint's policy was trained with (refused where it cannot serve here); auto,
    egl or tiny: that one, with a warning when the policy was trained on the other (its images differ)."""
    blind: Literal["", "fixation", "grasp", "both"] = ""
    """Show the policy another episode's images (another scene) in place of its own: in the fixation phase, the
    grasp phase or both (a blind baseline; with an environment target there is no fixation phase). Episodes are
    paired, so an odd --episodes is rounded up."""


def eval_checkpoint(path: Path) -> tuple[Path, dict]:
    """The checkpoint ``apr eval PATH`` evaluates, with its state: a run folder's newest intact one (those passed
    over are reported with the reason), or the given file; SystemExit saying what is expected otherwise."""
    from apr.train.checkpoints import CheckpointError, newest_intact, read_checkpoint

    expected = "give a run folder or a training checkpoint (RUN/checkpoints/checkpoint_*.pt)"
    path = Path(path)
    if not path.exists():
        raise SystemExit(f"apr eval: {path} does not exist; {expected}")
    if path.is_dir():
        if not (path / "checkpoints").is_dir() and not (path / "config.json").exists():
            raise SystemExit(f"apr eval: {path} is not a run folder (no checkpoints/, no config.json); {expected}")
        try:
            found = newest_intact(path, with_replay=False)
        except CheckpointError as error:
            raise SystemExit(f"apr eval: {error}") from None
        if found is None:
            raise SystemExit(f"apr eval: {path} has no checkpoint yet (checkpoints/checkpoint_*.pt)")
        return found
    if path.name == "config.json":
        raise SystemExit(f"apr eval: {path} is a run's configuration, not a checkpoint; give its run folder "
                         f"({path.parent}) or one of its checkpoints/checkpoint_*.pt")  # fmt: skip
    if path.suffix == ".npz":
        raise SystemExit(f"apr eval: {path} is a replay file (what a checkpoint resumes with), not a checkpoint; "
                         f"{expected}")  # fmt: skip
    if path.suffix == ".json" or path.with_suffix(".json").exists():
        raise SystemExit(f"apr eval: {path} is not a training checkpoint; a packaged checkpoint (NAME.json with its "
                         f"weights) runs with apr demo --checkpoint {path}; {expected}")  # fmt: skip
    try:
        return path, read_checkpoint(path)
    except CheckpointError as error:
        raise SystemExit(f"apr eval: {error}; {expected}") from None


def evaluate(args: EvalArgs) -> None:
    from apr.envs.rendering import EGL_INSTALL
    from apr.model.agent import APRAgent
    from apr.train.evaluation import RendererMismatch, renderer_request
    from apr.train.evaluation import evaluate as run_evaluation
    from apr.train.rollout import blind_phases_text

    checks.refuse("apr eval", [
        checks.at_least("--episodes", args.episodes, 1),
        checks.at_least("--workers", args.workers, 0),
        checks.output_file("--json", args.json) if args.json is not None else None,
    ])  # fmt: skip
    checkpoint, state = eval_checkpoint(args.path)
    config = TrainConfig.from_json(state["config"])
    if args.blind == "fixation" and not config.env.learned_fixation:
        raise SystemExit("apr eval: error: --blind fixation needs a learned fixation; this policy's environment picks "
                         "the target (it has no fixation phase): use --blind grasp or both")  # fmt: skip
    trained = state.get("renderer", "")
    if not trained:
        print(f"{checkpoint.name} does not record the renderer it was trained with (written before apr recorded "
              f"it): evaluating with the run's setting, renderer={config.env.renderer!r}, unchecked")  # fmt: skip
    asked = renderer_request(trained, config.env.renderer) if args.renderer == "trained" else args.renderer
    env = dataclasses.replace(config.env, renderer=asked)
    agent = APRAgent(config.model)
    agent.load_state_dict(state["agent"])
    mismatch = "refuse" if args.renderer == "trained" else "warn"
    try:
        result = run_evaluation(agent, env, args.episodes, args.split, args.workers or config.workers,
                                trained_renderer=trained, on_mismatch=mismatch, blind=args.blind)  # fmt: skip
    except RendererMismatch as refused:
        where = EGL_INSTALL if refused.trained == "egl" else f"evaluate where {refused.trained} serves"
        raise SystemExit(f"apr eval: error: {refused}. To measure the policy on its own images, {where}; or give "
                         f"--renderer {refused.actual} to evaluate it on these anyway") from None  # fmt: skip
    blind = f"; another scene's images in {blind_phases_text(args.blind)}" if args.blind else ""
    summary = (f"{checkpoint}: {result.success_rate:.1%} success on {result.episodes} {args.split} episodes "
               f"(95% CI {result.ci_low:.1%}-{result.ci_high:.1%}; renderer {result.renderer}{blind})")  # fmt: skip
    if result.fixation:
        stats = result.fixation
        summary += (f"\nfixation: median {stats['median_cm']:.1f} cm from the nearest object (one fixed point: "
                    f"{stats['fixed_median_cm']:.1f} cm, uniformly random points: "
                    f"{stats['uniform_median_cm']:.1f} cm), spread {stats['spread_x_cm']:.1f} x "
                    f"{stats['spread_y_cm']:.1f} cm")  # fmt: skip
    print(summary)
    if args.json:
        payload = {**result.to_dict(), "checkpoint": str(checkpoint), "grasps": state["progress"]["grasps"],
                   "trained_renderer": trained}  # fmt: skip
        args.json.write_text(json.dumps(payload, indent=2))


@dataclass
class PresetsArgs:
    """List the presets and what each changes from active-target."""

    markdown: bool = False
    """Print the table of docs/presets.md instead (:func:`presets_markdown`)."""


def list_presets(args: PresetsArgs) -> None:
    if args.markdown:
        print(presets_markdown(), end="")
        return
    base = _flat(PRESETS["active-target"][1])
    for name, (description, config) in PRESETS.items():
        changes = {k: v for k, v in _flat(config).items() if base.get(k) != v and k != "preset"}
        print(f"{name:34s} {description}")
        if changes and name != "active-target":
            print(" " * 35 + ", ".join(f"{k}={v}" for k, v in changes.items()))


PRESET_TABLE_FIELDS = ("env.env_id", "env.dof", "env.target", "env.foveation", "model.representation",
                       "model.fixation_reward", "model.fixation_relabels", "total_grasps")  # fmt: skip
"""The fields the presets table shows for every preset: what sets the rows of Table 1 apart, and the budget."""


def presets_markdown(compact: bool = False) -> str:
    """Every preset as a markdown table (docs/presets.md holds it, and the README the compact one; a test keeps them
    equal): its name, what it is and, unless ``compact``, the fields of :data:`PRESET_TABLE_FIELDS`."""
    if compact:
        lines = ["| preset | what it is |", "| --- | --- |"]
        lines += [f"| `{name}` | {description.replace('|', '/')} |" for name, (description, _) in PRESETS.items()]
        return "\n".join(lines) + "\n"
    header = ["preset", "what it is", *(f"`{name}`" for name in PRESET_TABLE_FIELDS)]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for name, (description, config) in PRESETS.items():
        flat = _flat(config)
        learned = config.env.learned_fixation
        values = [str(flat[field]) if learned or not field.startswith("model.fixation") else "-"
                  for field in PRESET_TABLE_FIELDS]  # fmt: skip
        lines.append(f"| `{name}` | {description.replace('|', '/')} | " + " | ".join(values) + " |")
    return "\n".join(lines) + "\n"


def _flat(config: TrainConfig) -> dict[str, object]:
    flat: dict[str, object] = {}
    for key, value in dataclasses.asdict(config).items():
        if isinstance(value, dict):
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    return flat
