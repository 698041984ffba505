"""A policy to run and picture, always with an honest label: a run's checkpoint, a packaged checkpoint, or an
untrained agent.

**Packaged checkpoints** live in ``src/apr/reproduce/checkpoints/``: ``NAME.json`` (the manifest: the
resolved training configuration, the grasps, the command that trained it, its final evaluation) beside
``NAME.pt`` (the networks' weights only, a plain tensor dict that ``torch.load(..., weights_only=True)`` reads
without running any pickled code) or ``NAME.safetensors`` (the same tensors; needs the ``safetensors``
package). ``apr reproduce package RUN_DIR`` writes one from a run; ``apr demo`` uses the first one it finds.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import torch
import tyro

from apr.envs.rendering import EGL_INSTALL, resolve
from apr.machine import machine_description
from apr.model.agent import APRAgent
from apr.model.pretrained import load_gqn_init
from apr.reproduce.runs import blind_eval_files, final_eval
from apr.train.checkpoints import CheckpointError, newest_intact, read_checkpoint
from apr.train.config import RENAMED_PRESETS, TrainConfig, preset
from apr.train.evaluation import renderer_mismatch, renderer_request
from apr.train.rollout import blind_phases_text

PACKAGED_DIR = Path(__file__).parent / "checkpoints"
"""Where packaged checkpoints live (inside the installed package)."""
MANIFEST_FORMAT = "apr-packaged-checkpoint/1"
UNTRAINED_PRESET = "smoke"
"""The preset whose (tiny) model the demo runs untrained when no packaged checkpoint exists."""


@dataclass
class PolicySnapshot:
    """An agent with the configuration it was trained with and what produced it."""

    agent: APRAgent
    config: TrainConfig
    grasps: int
    """Training grasps behind the weights (0: untrained)."""
    label: str
    """Says what the policy is: which run or package, at how many grasps, or that it is untrained."""
    trained: bool
    """False for freshly initialised weights, whatever the label."""
    source: str = ""
    """The file or folder it came from."""
    training: str = ""
    """How it was trained and what it measured, when known (packaged checkpoints): command, grasps, minutes,
    machine, held-out success."""
    renderer: str = ""
    """What its training images came from ("egl", "tiny", "mixed"), as the checkpoint records it; "" when it
    does not (untrained weights, or a checkpoint written before apr recorded it)."""


def new_agent(config: TrainConfig) -> APRAgent:
    """A freshly initialised agent for ``config`` (no torch.compile; the best local device)."""
    return APRAgent(config.model.replace(compile=False, device="auto"))


def starting_agent(config: TrainConfig) -> APRAgent:
    """The agent a run of ``config`` starts from: fresh weights, and the GQN's ``gqn_init`` if it names one."""
    agent = new_agent(config)
    load_gqn_init(agent)
    return agent


def untrained_snapshot(preset_name: str = UNTRAINED_PRESET, seed: int = 0) -> PolicySnapshot:
    """A freshly initialised agent of ``preset_name``: an UNTRAINED policy, labelled so."""
    config = dataclasses.replace(preset(preset_name), seed=seed).resolved()
    label = f"UNTRAINED policy (fresh weights of the {preset_name} preset, seed {seed}; 0 grasps of training)"
    return PolicySnapshot(starting_agent(config), config, 0, label, trained=False, source=f"preset {preset_name}")


def initial_snapshot(config: TrainConfig, run_name: str) -> PolicySnapshot:
    """The run's agent before training: the run's configuration and seed give the run's initial weights."""
    label = f"run {run_name} at 0 grasps (its initial, untrained weights)"
    return PolicySnapshot(starting_agent(config), config, 0, label, trained=False, source=run_name)


def run_checkpoints(run_dir: Path) -> list[Path]:
    """The checkpoints a run kept, by increasing grasps."""
    return sorted((run_dir / "checkpoints").glob("checkpoint_*.pt"))


def load_training_checkpoint(path: Path, state: dict | None = None) -> PolicySnapshot:
    """A training checkpoint (``RUN/checkpoints/checkpoint_XXXXXXXX.pt``; ``state``: its contents, if read)."""
    if state is None:
        try:
            state = read_checkpoint(path)
        except CheckpointError as error:
            raise SystemExit(str(error)) from None
    config = TrainConfig.from_json(state["config"])
    agent = new_agent(config)
    agent.load_state_dict(state["agent"])
    grasps = int(state["progress"]["grasps"])
    run_name = path.parent.parent.name
    trained = grasps > 0 and int(state["progress"].get("updates", 1)) > 0
    label = f"run {run_name} at {grasps:,} grasps ({path.name})"
    if not trained:
        label += ", no learner update yet: untrained weights"
    return PolicySnapshot(agent, config, grasps, label, trained=trained, source=str(path),
                          renderer=state.get("renderer", ""))  # fmt: skip


def load_run(run_dir: Path) -> PolicySnapshot:
    """The newest intact checkpoint of a run folder (newer damaged ones are reported and passed over)."""
    try:
        found = newest_intact(run_dir, with_replay=False)
    except CheckpointError as error:
        raise SystemExit(str(error)) from None
    if found is None:
        raise SystemExit(f"{run_dir} has no checkpoint (checkpoints/checkpoint_*.pt)")
    return load_training_checkpoint(*found)


def packaged_checkpoints(directory: Path = PACKAGED_DIR) -> list[Path]:
    """The manifests (``*.json``) of the packaged checkpoints in ``directory``, by name."""
    if not directory.is_dir():
        return []
    manifests = []
    for path in sorted(directory.glob("*.json")):
        try:
            if json.loads(path.read_text()).get("format") == MANIFEST_FORMAT:
                manifests.append(path)
        except (OSError, json.JSONDecodeError):
            continue
    return manifests


def follows_observation_rule(manifest_path: Path) -> bool:
    """Whether a packaged policy sees only what the robot can know: False where its training configuration hands
    the heads the target's true centre (``reveal_target``, as ``cpu-4d`` does)."""
    return not packaged_config(json.loads(manifest_path.read_text())).env.reveal_target


def packaged_config(manifest: dict) -> TrainConfig:
    """The training configuration a packaged checkpoint's manifest records."""
    return TrainConfig.from_json(json.dumps(manifest["config"]))


def packaged_by_name(name: str, directory: Path = PACKAGED_DIR) -> Path | None:
    """The manifest of the packaged checkpoint called ``name`` (its file name without ``.json``), or None."""
    return next((path for path in packaged_checkpoints(directory) if path.stem == name), None)


def load_packaged(manifest_path: Path) -> PolicySnapshot:
    """A packaged checkpoint, from its manifest (``NAME.json``) or its weights file."""
    if manifest_path.suffix != ".json":
        manifest_path = manifest_path.with_suffix(".json")
    manifest = json.loads(manifest_path.read_text())
    config = packaged_config(manifest)
    weights_path = manifest_path.parent / manifest["weights"]
    if weights_path.suffix == ".safetensors":
        try:
            from safetensors.torch import load_file
        except ImportError as error:
            raise SystemExit(f"{weights_path} needs the safetensors package: pip install safetensors") from error
        weights = load_file(str(weights_path), device="cpu")
    else:
        weights = torch.load(weights_path, map_location="cpu", weights_only=True)
    agent = new_agent(config)
    agent.networks.load_state_dict(weights)
    grasps = int(manifest["grasps"])
    label = f"packaged checkpoint {manifest_path.stem} ({config.preset}, {grasps:,} grasps)"
    return PolicySnapshot(agent, config, grasps, label, trained=grasps > 0, source=str(manifest_path),
                          training=training_description(manifest), renderer=manifest.get("renderer", ""))  # fmt: skip


def training_description(manifest: dict) -> str:
    """One sentence from a manifest: how the weights were trained, and their measured held-out success."""
    text = f"trained with `{manifest['command']}` for {int(manifest['grasps']):,} grasps"
    if manifest.get("train_minutes") is not None:
        text += f" in {manifest['train_minutes']:.1f} minutes of training"
    if manifest.get("machine"):
        text += f" on {manifest['machine']}"
    config = manifest.get("config", {})
    env, model = config.get("env", {}), config.get("model", {})
    if env.get("env_id"):
        text += f", in `{env['env_id']}`"
    if env.get("target") == "learned":
        relabels = int(model.get("fixation_relabels", 0))
        text += f", its fixation bandit learning from the {model.get('fixation_reward', 'grasp')} reward of the " + (
            f"point chosen and {relabels} relabelled points a sample" if relabels else "point chosen alone"
        )
    evaluation = manifest.get("final_eval")
    if evaluation:
        text += (
            f"; measured held-out success at those weights: {evaluation['successes']}/{evaluation['episodes']} "
            f"= {evaluation['success_rate']:.1%} (95% CI {evaluation['ci_low']:.1%}-{evaluation['ci_high']:.1%})"
        )
    else:
        text += "; no held-out evaluation of these exact weights was recorded"
    fixation = manifest.get("fixation")
    if fixation:
        text += (f"; its learned fixation looked a median {fixation['median_cm']:.2f} cm from the nearest object "
                 f"(the bin centre: {fixation['fixed_median_cm']:.2f} cm), its points spread "
                 f"{fixation['spread_x_cm']:.2f} x {fixation['spread_y_cm']:.2f} cm")  # fmt: skip
    for mode, result in manifest.get("blind", {}).items():  # measured later, on the same held-out episodes
        text += (f"; given another scene's images in {blind_phases_text(mode)} (blind): {result['successes']}/"
                 f"{result['episodes']} = {result['success_rate']:.1%}")  # fmt: skip
        if "own_successes" in result:
            text += f" (its own images in that measurement: {result['own_successes']}/{result['episodes']})"
    return text + "."


def picture_renderer(snapshot: PolicySnapshot, asked: str, command: str) -> tuple[str, str]:
    """The renderer of this process's environments that show ``snapshot``'s policy ("egl" or "tiny", as this
    process resolves it), and a warning when their images are not the kind the policy was trained on ("" when
    they are, or when the policy is untrained).

    Args:
        asked: "trained" (the policy's own renderer; where it cannot serve, the one that can, with the warning)
            or "auto", "egl", "tiny" (that one; the warning says when the policy was trained on the other).
        command: names the command in a refusal (an explicit "egl" that cannot serve).
    """
    trained = snapshot.renderer
    request = renderer_request(trained, snapshot.config.env.renderer) if asked == "trained" else asked
    try:
        actual = resolve(request)
    except RuntimeError as error:
        raise SystemExit(f"{command}: error: --renderer {asked}: {error}") from None
    if not snapshot.trained:
        return actual, ""
    if not trained:
        return actual, (f"the renderer {snapshot.label} was trained with is not recorded (written before apr "
                        f"recorded it); these episodes render with {actual}")  # fmt: skip
    problem = renderer_mismatch(trained, actual)
    if problem and asked != "trained":
        problem += f" (--renderer {asked} was asked for)"
    elif problem and trained == "egl":
        problem += f". To render with EGL, {EGL_INSTALL}"
    return actual, problem or ""


def load_policy(path: Path) -> PolicySnapshot:
    """A run folder (its latest checkpoint), a training checkpoint, or a packaged checkpoint."""
    path = Path(path)
    if path.is_dir():
        return load_run(path)
    if not path.exists():
        raise SystemExit(f"{path} does not exist")
    if path.suffix == ".json" or path.with_suffix(".json").exists():
        if path.with_suffix(".json") not in packaged_checkpoints(path.parent):
            raise SystemExit(f"{path} is not a packaged checkpoint (no {MANIFEST_FORMAT} manifest); give a run "
                             "folder, a training checkpoint or a packaged checkpoint's NAME.json")  # fmt: skip
        return load_packaged(path)
    return load_training_checkpoint(path)


def package_checkpoint(
    source: Path,
    out_dir: Path = PACKAGED_DIR,
    name: str = "",
    command: str = "",
    weights_format: str = "pt",
    machine: str = "",
) -> Path:
    """Write a packaged checkpoint (manifest and weights) from a run folder or a training checkpoint.

    Args:
        command: the command that trained it (recorded in the manifest; default: rebuilt from the config).
        machine: what it was trained on (default: this machine, ``apr.machine.machine_description``).
        weights_format: "pt" (torch tensors, no extra dependency) or "safetensors" (needs the package).

    Returns:
        The manifest's path.
    """
    snapshot = load_policy(source)
    run_dir = Path(source) if Path(source).is_dir() else Path(snapshot.source).parent.parent
    config = snapshot.config
    preset_now = RENAMED_PRESETS.get(config.preset, config.preset)  # the manifest's config keeps the old name
    name = name or f"{preset_now}__s{config.seed}__{snapshot.grasps}grasps"
    out_dir.mkdir(parents=True, exist_ok=True)
    weights = {key: value.detach().cpu().contiguous() for key, value in snapshot.agent.networks.state_dict().items()}
    if weights_format == "safetensors":
        from safetensors.torch import save_file

        weights_path = out_dir / f"{name}.safetensors"
        save_file(weights, str(weights_path))
    else:
        weights_path = out_dir / f"{name}.pt"
        torch.save(weights, weights_path)
    evaluation = final_eval(run_dir) if (run_dir / "eval").is_dir() else None
    if evaluation is not None and int(evaluation["grasps"]) != snapshot.grasps:
        evaluation = None  # an evaluation of other weights says nothing about these
    manifest = {
        "format": MANIFEST_FORMAT,
        "weights": weights_path.name,
        "preset": preset_now,
        "seed": config.seed,
        "grasps": snapshot.grasps,
        "command": command
        or f"apr train --preset {config.preset} --seed {config.seed} "
        f"--total-grasps {config.total_grasps} (other fields: see config)",
        "source": _relative(snapshot.source),
        "train_minutes": round(evaluation["train_s"] / 60, 1) if evaluation and "train_s" in evaluation else None,
        "machine": machine or machine_description(),
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "final_eval": {
            key: evaluation[key]
            for key in ("split", "episodes", "successes", "success_rate", "ci_low", "ci_high", "grasps")
        }
        if evaluation
        else None,
        "renderer": snapshot.renderer,
        "config": json.loads(config.to_json()),
    }
    if evaluation:
        if evaluation.get("fixation"):
            manifest["fixation"] = evaluation["fixation"]  # where the learned fixation looked on those episodes
        if blind := blind_results(run_dir, evaluation):
            manifest["blind"] = blind
    manifest_path = out_dir / f"{name}.json"
    manifest_path.write_text(json.dumps(manifest, indent=2))
    return manifest_path


def blind_results(run_dir: Path, evaluation: dict) -> dict:
    """The run's blind evaluations of the weights ``evaluation`` measured (``eval/blind_MODE_GRASPS.json``), by
    mode; each beside its own images' successes where the two ran the same held-out episodes (evaluation episodes
    are seeded alike, so equal counts are the same episodes)."""
    keep = ("successes", "episodes", "success_rate", "ci_low", "ci_high", "renderer")
    results = {}
    for path in blind_eval_files(run_dir, int(evaluation["grasps"])):
        blind = json.loads(path.read_text())
        results[blind["blind"]] = {key: blind[key] for key in keep if key in blind}
        if blind["episodes"] == evaluation["episodes"]:
            results[blind["blind"]]["own_successes"] = evaluation["successes"]
    return results


def _relative(path: str) -> str:
    """``path`` relative to the working directory when it lies under it (no machine's absolute paths shipped)."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


@dataclass
class PackageArgs:
    """Package a run's checkpoint for apr demo: its weights and a manifest, by default into the package."""

    source: Annotated[Path, tyro.conf.Positional]
    """A run folder (its latest checkpoint) or a training checkpoint file."""
    out: Path = PACKAGED_DIR
    """Folder for NAME.json and the weights (default: src/apr/reproduce/checkpoints, where apr demo looks)."""
    name: str = ""
    """File name without suffix; default: PRESET__sSEED__NGRASPSgrasps."""
    command: str = ""
    """The command that trained it, for the manifest (default: rebuilt from the run's configuration)."""
    machine: str = ""
    """What it was trained on, for the manifest (default: a description of this machine)."""
    weights_format: Literal["pt", "safetensors"] = "pt"
    """pt: a torch tensor dict (no extra dependency); safetensors: needs pip install safetensors."""


def run_package(args: PackageArgs) -> Path:
    manifest = package_checkpoint(args.source, args.out, args.name, args.command, args.weights_format, args.machine)
    print(f"wrote {manifest} and its weights; apr demo now uses it")
    return manifest
