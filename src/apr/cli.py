"""The ``apr`` command.

    apr train --preset NAME [--field value ...]   train (apr presets lists the presets)
    apr train --resume RUN_DIR                    continue a run from its latest checkpoint
    apr eval RUN_OR_CHECKPOINT --episodes N       evaluate on held-out objects
    apr presets                                   the presets of the paper's Table 1
    apr render --out DIR                          PNGs of one episode as the robot sees it
    apr bench env                                 environment speed against the raw ceiling
    apr bench learner                             milliseconds per joint GQN + SAC update

Every subcommand takes ``--help``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Annotated

import tyro

from apr.bench import env as env_bench
from apr.bench import learner as learner_bench
from apr.bench.env import EnvBenchArgs
from apr.bench.learner import LearnerBenchArgs
from apr.commands import render as render_command
from apr.commands import train as train_command
from apr.commands.render import RenderArgs
from apr.commands.train import EvalArgs, PresetsArgs


@dataclass
class BenchArgs:
    """Benchmarks; each prints what it measured."""

    benchmark: Annotated[
        Annotated[EnvBenchArgs, tyro.conf.subcommand("env")]
        | Annotated[LearnerBenchArgs, tyro.conf.subcommand("learner")],
        tyro.conf.arg(name=""),
    ]


Command = (
    Annotated[EvalArgs, tyro.conf.subcommand("eval")]
    | Annotated[PresetsArgs, tyro.conf.subcommand("presets")]
    | Annotated[RenderArgs, tyro.conf.subcommand("render")]
    | Annotated[BenchArgs, tyro.conf.subcommand("bench")]
)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["train"]:  # its defaults depend on --preset, so it parses its own arguments
        train_command.train(argv[1:])
        return
    command = tyro.cli(Command, args=argv, config=(tyro.conf.OmitSubcommandPrefixes,), description=__doc__)
    if isinstance(command, EvalArgs):
        train_command.evaluate(command)
    elif isinstance(command, PresetsArgs):
        train_command.list_presets(command)
    elif isinstance(command, RenderArgs):
        render_command.run(command)
    elif isinstance(command.benchmark, EnvBenchArgs):
        env_bench.run(command.benchmark)
    else:
        learner_bench.run(command.benchmark)


if __name__ == "__main__":
    main()
