"""The ``apr`` command.

    apr train --preset NAME [--field value ...]   train (apr presets lists the presets)
    apr train --resume RUN_DIR                    continue a run from its latest checkpoint
    apr eval RUN_OR_CHECKPOINT --episodes N       evaluate on held-out objects
    apr presets                                   the presets of the paper's Table 1
    apr render --out DIR                          PNGs of one episode as the robot sees it
    apr bench env                                 environment speed against the raw ceiling
    apr bench learner                             milliseconds per joint GQN + SAC update
    apr bench learning --preset cpu-4d            held-out success against grasps and minutes, beside baselines
    apr bench backends --preset cpu-4d            the same run with local workers and with Ray actors: speed, numbers
    apr bench vanilla --task benchmark            Stable-Baselines3 agents on apr's tasks, the same held-out episodes
    apr reproduce table1 --seeds S --grasps N     train the presets of Table 1 (resumable), write table1.md
    apr reproduce package RUN_DIR                 package a run's checkpoint for apr demo
    apr plot RUN_DIR... --out FILE                held-out success against grasps, one line per preset
    apr figures RUN_DIR --out DIR                 the paper's pictures (Figs 1, 3, 5, 6 and a GIF) of a run
    apr probe RUN_DIR | untrained:PRESET          what a representation knows: readouts on r, in cm held out
    apr demo                                      a policy on held-out objects, with a short report

Every subcommand takes ``--help``; ``apr --version`` prints the version.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Annotated

import tyro

from apr import __version__
from apr.bench import backends as backends_bench
from apr.bench import env as env_bench
from apr.bench import learner as learner_bench
from apr.bench import learning as learning_bench
from apr.bench import vanilla as vanilla_bench
from apr.bench.backends import BackendsBenchArgs
from apr.bench.env import EnvBenchArgs
from apr.bench.learner import LearnerBenchArgs
from apr.bench.learning import LearningBenchArgs
from apr.bench.vanilla import VanillaArgs
from apr.commands import backends as backends_command
from apr.commands import render as render_command
from apr.commands import train as train_command
from apr.commands.render import RenderArgs
from apr.commands.train import EvalArgs, PresetsArgs
from apr.reproduce import demo, figures, plot, policies, probe
from apr.reproduce.campaign import Table1Args
from apr.reproduce.demo import DemoArgs
from apr.reproduce.figures import FiguresArgs
from apr.reproduce.plot import PlotArgs
from apr.reproduce.policies import PackageArgs
from apr.reproduce.probe import ProbeArgs
from apr.reproduce.runs import UnreadableFile
from apr.train.checkpoints import CheckpointError, RunLocked
from apr.train.config import ConfigError


@dataclass
class TrainHelp:
    """Train APR from a preset, or continue a run: apr train --preset NAME | --resume RUN_DIR (see apr train --help)."""


@dataclass
class BenchArgs:
    """Benchmarks; each prints what it measured."""

    benchmark: Annotated[
        Annotated[EnvBenchArgs, tyro.conf.subcommand("env")]
        | Annotated[LearnerBenchArgs, tyro.conf.subcommand("learner")]
        | Annotated[LearningBenchArgs, tyro.conf.subcommand("learning")]
        | Annotated[BackendsBenchArgs, tyro.conf.subcommand("backends")]
        | Annotated[VanillaArgs, tyro.conf.subcommand("vanilla")],
        tyro.conf.arg(name=""),
    ]


@dataclass
class ReproduceArgs:
    """Reproducing the paper: Table 1 over presets and seeds, and packaging a checkpoint for the demo."""

    task: Annotated[
        Annotated[Table1Args, tyro.conf.subcommand("table1")] | Annotated[PackageArgs, tyro.conf.subcommand("package")],
        tyro.conf.arg(name=""),
    ]


Command = (
    Annotated[TrainHelp, tyro.conf.subcommand("train")]  # listed here; ``main`` hands ``apr train`` to its own parser
    | Annotated[EvalArgs, tyro.conf.subcommand("eval")]
    | Annotated[PresetsArgs, tyro.conf.subcommand("presets")]
    | Annotated[RenderArgs, tyro.conf.subcommand("render")]
    | Annotated[BenchArgs, tyro.conf.subcommand("bench")]
    | Annotated[ReproduceArgs, tyro.conf.subcommand("reproduce")]
    | Annotated[PlotArgs, tyro.conf.subcommand("plot")]
    | Annotated[FiguresArgs, tyro.conf.subcommand("figures")]
    | Annotated[ProbeArgs, tyro.conf.subcommand("probe")]
    | Annotated[DemoArgs, tyro.conf.subcommand("demo")]
)


HANDLERS = {
    EvalArgs: train_command.evaluate,
    PresetsArgs: train_command.list_presets,
    RenderArgs: render_command.run,
    Table1Args: backends_command.table1,
    PackageArgs: policies.run_package,
    PlotArgs: plot.run,
    FiguresArgs: figures.run,
    ProbeArgs: probe.run,
    DemoArgs: demo.run,
    EnvBenchArgs: env_bench.run,
    LearnerBenchArgs: learner_bench.run,
    LearningBenchArgs: learning_bench.run,
    BackendsBenchArgs: backends_bench.run,
    VanillaArgs: vanilla_bench.run,
}
"""What each parsed command runs (a group's chosen subcommand runs its own handler)."""


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--version"]:
        print(f"apr {__version__}")
        return
    try:
        if argv[:1] == ["train"]:  # its defaults depend on --preset, so it parses its own arguments
            train_command.train(argv[1:])
            return
        command = tyro.cli(Command, args=argv, config=(tyro.conf.OmitSubcommandPrefixes,), description=__doc__)
        if isinstance(command, BenchArgs):
            command = command.benchmark
        elif isinstance(command, ReproduceArgs):
            command = command.task
        HANDLERS[type(command)](command)
    except (ConfigError, RunLocked, CheckpointError) as error:  # refusals: a message, not a traceback
        raise SystemExit("\n".join(f"apr {argv[0]}: error: {line}" for line in str(error).splitlines())) from None
    except UnreadableFile as error:  # a damaged file of a run folder, by name
        raise SystemExit(f"apr {argv[0]}: error: {error}") from None
    except OSError as error:  # a path that is missing, unreadable or cannot be made
        where = f": {error.filename}" if error.filename else ""
        raise SystemExit(f"apr {argv[0]}: error: {error.strerror or error}{where}") from None


if __name__ == "__main__":
    main()
