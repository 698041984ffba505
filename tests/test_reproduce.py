"""The reproduction layer: Table 1, the learning-curve plot, the figures and the demo.

The table and the plot are checked against fabricated run folders (synthetic config.json, metrics.csv and
eval files for every preset, no training): the rendered numbers must be exactly those of the files. The
commands that need a checkpoint share ONE real tiny training run, made by ``apr reproduce table1`` itself
(module-scoped fixture).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import statistics
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from apr.cli import main
from apr.model.agent import APRAgent
from apr.model.config import ModelConfig
from apr.reproduce import campaign, demo, figures, plot, policies
from apr.reproduce.campaign import Table1Args, plan_runs
from apr.reproduce.episodes import make_env
from apr.reproduce.orderings import PAPER_ORDERINGS, Difference, bootstrap_difference, evaluations_for, verdict
from apr.reproduce.paper import PAPER_PRESETS, PAPER_TABLE1
from apr.reproduce.policies import PolicySnapshot, load_training_checkpoint, package_checkpoint, run_checkpoints
from apr.reproduce.table import build_table1, render_table1, write_table1
from apr.train.config import preset
from apr.train.evaluation import wilson_interval
from apr.train.trainer import METRICS_COLUMNS

TINY_RUN = dict(
    total_grasps=2,
    workers=1,
    random_grasps=1,
    eval_episodes=1,
    eval_every_grasps=0,
    checkpoint_every_grasps=1,
    image_every_grasps=0,
    log_every_grasps=1,
)
"""The smoke preset shrunk further: 2 grasps (1 random), 1 evaluation episode at the end, a checkpoint a grasp."""

PAPER_SAYS = {
    "active-target": "84%",
    "passive-target": "76%",
    "active-target-no-logpolar": "79%",
    "active-target-no-representation": "negligible improvement",
    "active-learned-6d": "85% after 70K grasps",
    "active-learned-4d": "85% after 25K grasps",
}


# ------------------------------------------------------------------------------------------- fabricated runs
def fabricate_run(
    root: Path,
    preset_name: str,
    seed: int,
    evaluations: list[tuple[int, int, int]],
    finished: bool = True,
    at_limit: int = 0,
) -> Path:
    """A run folder without training: config.json, and per (grasps, successes, episodes) an eval file and a
    metrics.csv row (with a row without evaluation before each); ``finished``: the last one is the run's final
    evaluation; ``at_limit`` episodes of each evaluation ended at the limit without an attempt."""
    run_dir = root / f"{preset_name}__s{seed}"
    (run_dir / "eval").mkdir(parents=True)
    (run_dir / "config.json").write_text(dataclasses.replace(preset(preset_name), seed=seed).to_json())
    rows = []
    for grasps, successes, episodes in evaluations:
        low, high = wilson_interval(successes, episodes)
        result = {
            "split": "test",
            "episodes": episodes,
            "successes": successes,
            "success_rate": successes / episodes,
            "ci_low": low,
            "ci_high": high,
            "attempts": episodes - at_limit,
            "lost": 0,
            "outcomes": [],
            "grasps": grasps,
            "final": finished and grasps == evaluations[-1][0],
        }
        (run_dir / "eval" / f"eval_{grasps:08d}.json").write_text(json.dumps(result))
        blank = dict.fromkeys(METRICS_COLUMNS, "")
        rows.append({**blank, "grasps": grasps - 1, "train_success": 0.5})
        rows.append(
            {**blank, "grasps": grasps, "eval_success": successes / episodes, "eval_ci_low": low, "eval_ci_high": high}
        )
    with open(run_dir / "metrics.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=METRICS_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return run_dir


def table_cells(markdown: str) -> dict[str, list[str]]:
    """The cells of Table 1's rows (the first table of the markdown), by preset."""
    table = markdown.split("\n## ")[0]
    rows = {}
    for line in table.splitlines():
        if line.startswith("| ") and not line.startswith(("| preset", "| ---")):
            cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
            rows[cells[0]] = cells
    return rows


def test_table1_shows_exactly_the_numbers_of_the_final_eval_files(tmp_path: Path):
    finals: dict[str, list[tuple[int, int]]] = {}
    for number, name in enumerate(PAPER_PRESETS):
        if name == "active-target-no-representation":
            continue  # a preset without runs must still get its row
        finals[name] = []
        for seed in range(2):
            successes, episodes = 40 + 7 * number + 11 * seed, 100 + 20 * seed
            # an earlier evaluation with other numbers: the table must take the one with the most grasps
            fabricate_run(
                tmp_path, name, seed, [(500, 3, 100), (1000 + 10 * number, successes, episodes)], at_limit=seed + 1
            )
            finals[name].append((successes, episodes))

    markdown = render_table1(build_table1([tmp_path]))
    rows = table_cells(markdown)

    assert set(rows) == set(PAPER_PRESETS)
    for name, says in PAPER_SAYS.items():
        assert says in rows[name][1], name
    assert rows["active-target-no-representation"][2].startswith("not run")
    for name, seeds in finals.items():
        total_successes = sum(s for s, _ in seeds)
        total_episodes = sum(n for _, n in seeds)
        low, high = wilson_interval(total_successes, total_episodes)
        expected = (
            f"{100 * total_successes / total_episodes:.1f}% ({total_successes}/{total_episodes}) "
            f"[{100 * low:.1f}%, {100 * high:.1f}%]"
        )
        assert rows[name][2] == expected
        rates = [s / n for s, n in seeds]
        assert rows[name][3] == f"{100 * statistics.mean(rates):.1f}% ± {100 * statistics.stdev(rates):.1f} pts"
        assert rows[name][4] == "-"  # no blind evaluation
        assert rows[name][5] == f"{total_episodes - 3}/{total_episodes} ({300 / total_episodes:.1f}% at the limit)"
        assert rows[name][6] == "2 (s0, s1)"
        assert rows[name][8] == str(total_episodes)
    assert rows["active-target"][7] == "1,000"  # the grasps of the final evaluations
    assert rows["active-learned-4d"][7] == f"{1000 + 10 * PAPER_PRESETS.index('active-learned-4d'):,}"
    assert "3/100" not in markdown.split("## Runs")[0]  # the earlier evaluations are not reported
    assert "eval_00001000.json" in markdown  # each run's final evaluation file is named


def test_table1_campaign_skips_finished_resumes_checkpointed_and_restarts_the_rest(tmp_path: Path):
    fabricate_run(tmp_path, "smoke", 0, [(8, 1, 2)])  # evaluated at the budget: done
    resumable = fabricate_run(tmp_path, "smoke", 1, [(4, 1, 2)], finished=False)  # half-way, with a checkpoint
    (resumable / "checkpoints").mkdir()
    (resumable / "checkpoints" / "checkpoint_00000004.pt").write_bytes(b"")
    fabricate_run(tmp_path, "smoke", 2, [(4, 1, 2)], finished=False)  # half-way, no checkpoint: start over

    plans = plan_runs(["smoke"], [0, 1, 2, 3], tmp_path, {"total_grasps": 8})

    assert [plan.status for plan in plans] == ["done", "resume", "restart", "new"]
    assert [plan.run_dir.name for plan in plans] == ["smoke__s0", "smoke__s1", "smoke__s2", "smoke__s3"]
    assert all(plan.config.total_grasps == 8 and plan.config.seed == seed for seed, plan in enumerate(plans))
    more = plan_runs(["smoke"], [0], tmp_path, {"total_grasps": 16})  # a larger budget continues a finished run
    assert more[0].status == "restart"  # (smoke__s0 has no checkpoint in this fabricated folder)


def test_plot_draws_one_line_per_preset_with_the_spread_across_seeds(tmp_path: Path):
    curves = {
        "active-target": [(1, 3, 5), (2, 4, 8)],
        "passive-target": [(0, 1, 2), (1, 1, 3)],
        "smoke": [(2, 2, 2), (0, 2, 4)],
    }  # preset -> per seed, successes (of 10) at grasps 100, 200, 300
    for name, seeds in curves.items():
        for seed, successes in enumerate(seeds):
            fabricate_run(tmp_path, name, seed, [(100 * (k + 1), s, 10) for k, s in enumerate(successes)])

    figure = plot.plot_learning_curves([tmp_path])

    axes = figure.axes[0]
    assert len(axes.lines) == len(curves)
    assert len(axes.collections) == len(curves)  # one shaded band per preset
    for line, band, (name, seeds) in zip(axes.lines, axes.collections, curves.items(), strict=True):
        assert line.get_label().startswith(name)
        rates = np.array(seeds) / 10
        assert np.allclose(line.get_xdata(), [100, 200, 300])
        assert np.allclose(line.get_ydata(), 100 * rates.mean(axis=0))
        top = band.get_paths()[0].vertices[:, 1].max()
        assert top == pytest.approx(100 * (rates.mean(axis=0) + rates.std(axis=0, ddof=1)).max())


def fabricate_blind(run_dir: Path, grasps: int, successes: int, episodes: int) -> None:
    """The blind evaluation of a fabricated run's policy at ``grasps``."""
    result = {"blind": "both", "episodes": episodes, "successes": successes, "success_rate": successes / episodes,
              "grasps": grasps}  # fmt: skip
    (run_dir / "eval" / f"blind_both_{grasps:08d}.json").write_text(json.dumps(result))


CPU_SEEDS = {  # paper row -> per seed (successes of 30 at 200 grasps, of 100 at 600, blind successes of 100 or None)
    "active-target": [(9, 70, 20), (12, 72, 30), (15, 68, None)],
    "passive-target": [(15, 50, 10), (15, 50, 20), (15, 50, 30)],
    "active-target-no-logpolar": [(3, 95, 5), (3, 99, 5), (3, 97, 5)],
    "active-target-no-representation": [(6, 69, 1), (9, 71, 2), (12, 70, 3)],
    "passive-target-no-representation": [(3, 20, 20), (3, 21, 20), (3, 19, 20)],
    "active-learned-6d": [(27, 10, 9)],
    "active-learned-4d": [(18, 60, 50), (21, 70, 40), (24, 80, 30)],
}


def test_cpu_table_gives_the_known_means_blind_successes_and_each_claim_in_its_direction(tmp_path: Path):
    runs = tmp_path / "runs"
    for row, seeds in CPU_SEEDS.items():
        for seed, (early, successes, blind) in enumerate(seeds):
            run_dir = fabricate_run(runs, "cpu-" + row, seed, [(200, early, 30), (600, successes, 100)])
            if blind is not None:
                fabricate_blind(run_dir, 600, blind, 100)
    out = write_table1([runs], tmp_path / "table1.md", [f"cpu-{row}" for row in CPU_SEEDS])

    table = json.loads(out.with_name("table1.json").read_text())
    by_row = {row["paper_row"]: row for row in table["rows"]}
    for row, seeds in CPU_SEEDS.items():
        rates = [successes / 100 for _, successes, _ in seeds]
        blinds = [blind / 100 for _, _, blind in seeds if blind is not None]
        assert by_row[row]["preset"] == "cpu-" + row
        assert by_row[row]["seed_mean"] == pytest.approx(statistics.mean(rates))
        assert by_row[row]["blind_mean"] == pytest.approx(statistics.mean(blinds))
        assert [seed["success_rate"] for seed in by_row[row]["seeds"]] == pytest.approx(rates)
        assert all(seed["grasps"] == 600 and seed["episodes"] == 100 for seed in by_row[row]["seeds"])
    found = {(item["first"], item["second"], item["measure"]): item for item in table["orderings"]}
    assert all(item["sentence"] for item in found.values())  # every claim carries the paper's words
    active = found["cpu-active-target", "cpu-passive-target", "final"]  # 70% (70, 72, 68) against 50% (all 50)
    assert active["difference"] == pytest.approx(0.2) and active["seeds"] == [3, 3]
    # the seeds' spread and 100 episodes each (a binomial's standard deviation of ~2.6 points for a row's mean)
    assert 0.1 < active["ci_low"] < 0.2 < active["ci_high"] < 0.3 and active["verdict"] == "holds"
    # the curve: the mean of the 200- and 600-grasp evaluations, (0.4 + 0.7) / 2 against (0.5 + 0.5) / 2
    curve = found["cpu-active-target", "cpu-passive-target", "curve"]
    assert curve["difference"] == pytest.approx(0.05)
    assert found["cpu-active-target", "cpu-active-target-no-logpolar", "final"]["verdict"] == "reversed"  # 70 vs 97
    # "negligible improvement" without representation learning: active-target ahead; 70 against 70 is not that
    representation = found["cpu-active-target", "cpu-active-target-no-representation", "final"]
    assert representation["difference"] == pytest.approx(0.0, abs=1e-9)
    assert representation["verdict"] == "not resolved"
    passive = found["cpu-passive-target", "cpu-passive-target-no-representation", "final"]  # 50 against 20
    assert passive["difference"] == pytest.approx(0.3) and passive["verdict"] == "holds"
    one_seed = found["cpu-active-learned-6d", "cpu-active-target", "final"]  # 10 against 70, but one seed
    assert one_seed["difference"] == pytest.approx(-0.6) and one_seed["verdict"] == "not resolved"
    early = found["cpu-active-learned-6d", "cpu-active-target", "early"]  # the 200-grasp evaluation: 27 of 30
    assert early["difference"] == pytest.approx(0.9 - 0.4)
    markdown = out.read_text()
    rows = table_cells(markdown)
    assert rows["cpu-active-target"][1] == "84%"  # the paper's number beside its CPU scale
    assert rows["cpu-active-target"][4] == "25.0% (2 of 3 seeds)"
    assert '"We observe that the active model achieves 8% better performance."' in markdown
    assert "**holds**" in markdown and "they do not reproduce the paper's numbers" in markdown
    assert iio.imread(out.with_name("figure4.png")).ndim == 3


def test_bootstrap_interval_and_verdicts_on_known_seeds():
    certain = bootstrap_difference([[(100, 100)]] * 3, [[(0, 100)]] * 2)  # rates of 1 and 0 resample to themselves
    assert (certain.difference, certain.low, certain.high) == pytest.approx((1.0, 1.0, 1.0))
    spread = bootstrap_difference([[(0, 100)], [(100, 100)]], [[(0, 100)]])  # means 0 (1/4), 0.5 (1/2), 1 (1/4)
    assert (spread.difference, spread.low, spread.high) == pytest.approx((0.5, 0.0, 1.0))
    assert bootstrap_difference([[(1, 100)]], [[(2, 50)]]) == bootstrap_difference([[(1, 100)]], [[(2, 50)]])
    agreeing = bootstrap_difference([[(1, 100)]] * 3, [[(0, 100)]] * 3)  # seeds that agree: the episodes still vary
    assert agreeing.difference == pytest.approx(0.01) and agreeing.low <= 0 < agreeing.high
    curves = bootstrap_difference([[(100, 100), (0, 100)]] * 3, [[(50, 100), (50, 100)]] * 3)  # each seed's mean
    assert curves.difference == pytest.approx(0.0, abs=1e-12)
    assert verdict(agreeing) == "not resolved"
    assert verdict(certain) == "holds"
    assert verdict(certain, seeds=(3, 2)) == "not resolved"  # fewer than MIN_SEEDS in a row
    assert verdict(Difference(-0.2, -0.3, -0.1)) == "reversed"
    with pytest.raises(ValueError, match="at least one seed"):
        bootstrap_difference([], [[(1, 2)]])


def test_each_measure_reads_its_evaluations():
    evaluations = [(0, 0, 30), (200, 3, 30), (400, 6, 30), (600, 50, 100)]
    assert evaluations_for("final", evaluations) == [(50, 100)]
    assert evaluations_for("curve", evaluations) == [(3, 30), (6, 30), (50, 100)]  # after the first grasp
    assert evaluations_for("early", evaluations) == [(3, 30)]  # within the first third of 600 grasps


PAPER_TEX = Path(__file__).resolve().parents[2] / "shared" / "paper" / "apr-paper.tex"


def test_every_claim_reads_the_paper_in_its_direction():
    for ordering in PAPER_ORDERINGS:
        assert ordering.first in PAPER_TABLE1 and ordering.second in PAPER_TABLE1 and ordering.sentence
    by_claim = {(o.first, o.second, o.measure) for o in PAPER_ORDERINGS}
    assert ("active-target", "active-target-no-representation", "final") in by_claim  # "negligible improvement"
    assert ("active-learned-6d", "active-target", "early") in by_claim  # "learns faster in the initial stages"
    assert ("active-learned-6d", "active-target", "final") in by_claim  # "slightly better in final performance"
    assert ("passive-target", "passive-target-no-representation", "final") in by_claim  # "benefited both"


@pytest.mark.skipif(not PAPER_TEX.exists(), reason="the paper's source is not beside this checkout")
def test_every_claim_quotes_the_papers_words():
    text = " ".join(PAPER_TEX.read_text().split()).replace("\\%", "%")
    for ordering in PAPER_ORDERINGS:
        for part in ordering.sentence.split("..."):
            assert part.strip() in text, part


COMMITTED_TABLE = Path(__file__).resolve().parents[1] / "results" / "table1-cpu"


def test_table_only_rebuilds_the_committed_cpu_table(tmp_path: Path, monkeypatch):
    copy = tmp_path / "results" / "table1-cpu"
    for path in COMMITTED_TABLE.rglob("*"):  # the committed small files only: no checkpoint is needed
        if path.is_file() and path.suffix in (".json", ".csv", ".md"):
            (copy / path.relative_to(COMMITTED_TABLE)).parent.mkdir(parents=True, exist_ok=True)
            (copy / path.relative_to(COMMITTED_TABLE)).write_bytes(path.read_bytes())
    for name in ("table1.md", "table1.json", "figure4.png"):
        (copy / name).unlink(missing_ok=True)
    monkeypatch.chdir(tmp_path)

    campaign.run(Table1Args(scale="cpu", out=Path("results/table1-cpu"), table_only=True))

    for name in ("table1.md", "table1.json"):
        assert (copy / name).read_text() == (COMMITTED_TABLE / name).read_text(), name
    assert iio.imread(copy / "figure4.png").ndim == 3


# ------------------------------------------------------------------------------------ one real training run
@pytest.fixture(scope="module")
def table1_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``apr reproduce table1`` over the smoke preset, one seed, shrunk to 2 grasps: a real run folder."""
    out = tmp_path_factory.mktemp("table1")
    campaign.run(Table1Args(seeds=1, presets=("smoke",), out=out), overrides=TINY_RUN)
    return out


@pytest.fixture(scope="module")
def run_dir(table1_out: Path) -> Path:
    return table1_out / "smoke__s0"


def test_table1_command_trains_writes_the_table_then_skips_the_finished_run(table1_out, run_dir, monkeypatch):
    result = json.loads((run_dir / "eval" / "eval_00000002.json").read_text())
    rows = table_cells((table1_out / "table1.md").read_text())
    low, high = result["ci_low"], result["ci_high"]
    rate = result["success_rate"]
    assert rows["smoke"][2] == (
        f"{100 * rate:.1f}% ({result['successes']}/{result['episodes']}) [{100 * low:.1f}%, {100 * high:.1f}%]"
    )
    assert rows["smoke"][7] == "2"
    assert len(run_checkpoints(run_dir)) == 2
    blind = json.loads((run_dir / "eval" / "blind_both_00000002.json").read_text())  # the final policy, blind
    assert blind["blind"] == "both" and blind["episodes"] == 2 and blind["grasps"] == 2  # paired: rounded up to even
    assert json.loads((table1_out / "table1.json").read_text())["rows"][0]["seeds"][0]["blind"]["episodes"] == 2
    assert (table1_out / "figure4.png").exists()

    def no_training(*args, **kwargs):
        raise AssertionError("a finished run was trained again")

    monkeypatch.setattr(campaign, "train_planned", no_training)
    (table1_out / "table1.md").unlink()
    (run_dir / "eval" / "blind_both_00000002.json").unlink()  # finished before blind evaluations were asked for
    campaign.run(Table1Args(seeds=1, presets=("smoke",), out=table1_out), overrides=TINY_RUN)
    assert table_cells((table1_out / "table1.md").read_text())["smoke"] == rows["smoke"]
    again = json.loads((run_dir / "eval" / "blind_both_00000002.json").read_text())  # evaluated again
    assert again.pop("eval_s") > 0 and blind.pop("eval_s") > 0
    assert again == blind


def test_plot_command_on_a_real_run_writes_a_picture(run_dir: Path, tmp_path: Path):
    out = tmp_path / "curves.png"
    main(["plot", str(run_dir), "--out", str(out)])
    image = iio.imread(out)
    assert image.ndim == 3 and image.shape[0] > 200 and image.shape[1] > 300


def test_figures_command_writes_every_picture_captioned_with_its_policy(run_dir: Path, tmp_path: Path):
    out = tmp_path / "figures"
    main(["figures", str(run_dir), "--out", str(out), "--episodes", "1", "--steps", "3"])

    for name in ("fig1_logpolar", "fig3_active_vs_passive", "fig5_pregrasp", "fig6_gqn_predictions"):
        image = iio.imread(out / f"{name}.png")
        assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100, name
    frames = iio.imread(out / "episodes.gif", index=None)
    assert frames.ndim == 4 and frames.shape[0] >= 3 and frames.shape[1:3] == (256 + 34, 512)
    captions = (out / "figures.md").read_text()
    assert captions.count("run smoke__s0 at 2 grasps (checkpoint_00000002.pt)") >= 2  # the GIF and Fig. 5
    assert "driven by the scripted reach-and-grasp" in captions  # smoke learns its fixation: no passive twin


def test_gqn_figure_has_a_prediction_per_checkpoint_and_skips_a_model_without_generator(run_dir: Path):
    snapshots = [load_training_checkpoint(path) for path in run_checkpoints(run_dir)]
    config = snapshots[0].config
    env = make_env(config.env, "test", renderer="tiny")
    try:
        observation, _ = env.reset(seed=0)
    finally:
        env.close()

    figure, caption = figures.gqn_figure(snapshots, [observation, observation], "run smoke__s0")

    assert len(figure.axes) == 2 * (3 + len(snapshots))
    titles = [axes.get_title() for axes in figure.axes[:5]]
    assert titles[3:] == ["predicted\n1 grasps", "predicted\n2 grasps"]
    assert "run smoke__s0" in caption
    without = APRAgent(ModelConfig.tiny(representation=False, image_channels=3, grasp_action_dim=4))
    ablation = PolicySnapshot(without, config, 0, "no generator", trained=False)
    assert figures.gqn_figure([ablation], [observation], "ablation") is None


def test_pictures_render_with_the_policys_own_renderer_and_say_so_when_they_cannot(monkeypatch):
    from apr.reproduce import policies

    def snapshot(renderer: str, trained: bool = True) -> PolicySnapshot:
        return PolicySnapshot(None, preset("smoke"), 5, "run x at 5 grasps", trained=trained, renderer=renderer)

    assert policies.picture_renderer(snapshot("tiny"), "trained", "apr demo") == ("tiny", "")
    renderer, warning = policies.picture_renderer(snapshot("egl"), "tiny", "apr demo")
    assert renderer == "tiny" and "trained on egl images" in warning and "--renderer tiny was asked for" in warning
    assert policies.picture_renderer(snapshot("", trained=False), "tiny", "apr demo") == ("tiny", "")
    assert "is not recorded" in policies.picture_renderer(snapshot(""), "tiny", "apr demo")[1]

    monkeypatch.setattr(policies, "resolve", lambda renderer: "tiny")  # a machine where EGL does not load
    renderer, warning = policies.picture_renderer(snapshot("egl"), "trained", "apr demo")
    assert renderer == "tiny" and "EGL plugin does not load here" in warning and "apt-get install" in warning

    def no_egl(renderer: str) -> str:
        raise RuntimeError("renderer='egl' was asked for but pybullet's EGL plugin did not load")

    monkeypatch.setattr(policies, "resolve", no_egl)
    with pytest.raises(SystemExit, match="apr demo: error: --renderer egl: renderer='egl' was asked for"):
        policies.picture_renderer(snapshot("egl"), "egl", "apr demo")


def test_demo_without_a_packaged_checkpoint_runs_an_untrained_policy_and_says_so(tmp_path: Path, capsys):
    result = demo.run(demo.DemoArgs(out=tmp_path / "demo", episodes=1, gif_episodes=1), packaged_dir=tmp_path)

    report = result.report.read_text()
    assert "**UNTRAINED POLICY.**" in report and "No trained checkpoint is packaged" in report
    assert "UNTRAINED" in capsys.readouterr().out
    assert not result.snapshot.trained
    numbers = json.loads((tmp_path / "demo" / "result.json").read_text())
    assert numbers["trained"] is False and numbers["episodes"] == 1
    assert f"{numbers['successes']}/1 held-out episodes succeeded" in report
    assert iio.imread(tmp_path / "demo" / "episodes.gif", index=None).shape[0] >= 2
    assert iio.imread(tmp_path / "demo" / "fig1_logpolar.png").ndim == 3


def test_a_packaged_checkpoint_dropped_in_is_what_the_demo_runs_and_reports(run_dir: Path, tmp_path: Path):
    packaged = tmp_path / "checkpoints"
    manifest = package_checkpoint(run_dir, packaged, command="pytest tiny smoke run", machine="the test machine")
    written = json.loads(manifest.read_text())
    assert written["final_eval"]["grasps"] == 2 and written["machine"] == "the test machine"
    assert written["train_minutes"] is not None
    blind = json.loads((run_dir / "eval" / "blind_both_00000002.json").read_text())  # the run's blind evaluation
    assert written["blind"]["both"]["successes"] == blind["successes"]
    # the blind pairs round 1 episode up to 2: not the final evaluation's episodes, so no own-images figure beside it
    assert blind["episodes"] == 2 != written["final_eval"]["episodes"]
    assert "own_successes" not in written["blind"]["both"]
    trained = load_training_checkpoint(run_checkpoints(run_dir)[-1])
    assert trained.trained, "the tiny run should have made learner updates"

    snapshot = demo.choose_policy(None, packaged)

    assert snapshot.trained and snapshot.grasps == 2 and "packaged checkpoint" in snapshot.label
    for key, value in trained.agent.networks.state_dict().items():
        assert torch.equal(snapshot.agent.networks.state_dict()[key], value), key
    assert demo.untrained_notice(snapshot, packaged) == ""
    assert written["renderer"] == trained.renderer == snapshot.renderer and trained.renderer in ("egl", "tiny")
    result = demo.run(demo.DemoArgs(out=tmp_path / "demo", episodes=1, gif_episodes=1), packaged_dir=packaged)
    assert result.renderer == trained.renderer and result.renderer_warning == ""  # the policy's own images
    report = result.report.read_text()
    assert "UNTRAINED" not in report
    assert f"**Policy:** packaged checkpoint {manifest.stem} (smoke, 2 grasps)" in report
    final = written["final_eval"]
    model = written["config"]["model"]
    assert (f"**Training:** trained with `pytest tiny smoke run` for 2 grasps in {written['train_minutes']:.1f} "
            f"minutes of training on the test machine, in `{written['config']['env']['env_id']}`, its fixation bandit "
            f"learning from the {model['fixation_reward']} reward of the point chosen alone; measured held-out "
            f"success at those weights: {final['successes']}/{final['episodes']}"
            ) in report  # fmt: skip
    assert iio.imread(tmp_path / "demo" / "fig5_pregrasp.png").ndim == 3


def test_the_demo_runs_a_packaged_policy_that_follows_the_observation_rule_and_others_by_name(run_dir: Path,
                                                                                          tmp_path: Path):  # fmt: skip
    packaged = tmp_path / "checkpoints"
    # "a-privileged" sorts first: by name alone the demo would run it
    privileged = package_checkpoint(run_dir, packaged, name="a-privileged", machine="the test machine")
    manifest = json.loads(privileged.read_text())
    manifest["config"]["env"]["reveal_target"] = True
    privileged.write_text(json.dumps(manifest))
    following = package_checkpoint(run_dir, packaged, name="b-follows-the-rule", machine="the test machine")

    assert not policies.follows_observation_rule(privileged) and policies.follows_observation_rule(following)
    assert "b-follows-the-rule" in demo.choose_policy(None, packaged).label
    assert "a-privileged" in demo.choose_policy(Path("a-privileged"), packaged).label
    following.unlink()  # no packaged policy follows the rule: the first one, as before
    assert "a-privileged" in demo.choose_policy(None, packaged).label
    with pytest.raises(SystemExit, match="--checkpoint no-such-policy is neither a path nor a checkpoint packaged"):
        demo.run(demo.DemoArgs(out=tmp_path / "demo", checkpoint=Path("no-such-policy")), packaged_dir=packaged)


def test_a_packaged_policys_description_gives_its_blind_numbers_beside_its_success():
    from apr.reproduce.policies import training_description

    own = {"successes": 82, "episodes": 100, "success_rate": 0.82, "ci_low": 0.73, "ci_high": 0.88}
    blind = {"successes": 85, "episodes": 100, "success_rate": 0.85, "own_successes": 80}
    manifest = {"command": "apr train --preset cpu-4d --seed 1", "grasps": 584, "final_eval": own,
                "blind": {"both": blind}}  # fmt: skip
    text = training_description(manifest)
    assert "82/100 = 82.0%" in text
    assert text.endswith("given another scene's images in every phase (blind): 85/100 = 85.0% (its own images in "
                         "that measurement: 80/100).")  # fmt: skip
    manifest["fixation"] = {"median_cm": 3.98, "fixed_median_cm": 5.4, "spread_x_cm": 1.99, "spread_y_cm": 2.24}
    assert ("; its learned fixation looked a median 3.98 cm from the nearest object (the bin centre: 5.40 cm), its "
            "points spread 1.99 x 2.24 cm; given another") in training_description(manifest)  # fmt: skip
    del manifest["blind"]["both"]["own_successes"]
    assert training_description(manifest).endswith("another scene's images in every phase (blind): 85/100 = 85.0%.")
    del manifest["final_eval"], manifest["fixation"]
    assert "no held-out evaluation of these exact weights was recorded; given another scene's" in (
        training_description(manifest))  # fmt: skip


def test_figure_3_drives_the_policy_in_its_own_environment_settings():
    """The Figure 3 episode's environments keep what the run's policy was trained on: its render size, and for
    the privileged cpu-4d the revealed target its heads read (before, a fresh EnvConfig dropped both)."""
    from apr.reproduce.figures import fig3_driver
    from apr.reproduce.policies import initial_snapshot
    from apr.train.config import preset

    snapshot = initial_snapshot(preset("cpu-4d").resolved(), "cpu-4d__s0")
    own, replay, policy, _ = fig3_driver(snapshot)
    assert policy is not None and own.env_id == "apr/ActiveGrasp-v4" and replay.env_id == "apr/PassiveGrasp-v4"
    assert own.reveal_target and own.render_size == 128 and own.renderer == "tiny" and own.dof == 4
    assert replay.foveation == "resize" and replay.render_size == 128
    learned = initial_snapshot(preset("cpu-learned-4d").resolved(), "cpu-learned-4d__s0")
    driver, _, policy, _ = fig3_driver(learned)
    assert policy is None and driver.target == "env" and not driver.reveal_target  # the scripted policy drives


def test_the_shipped_demo_runs_a_trained_policy_that_follows_the_observation_rule():
    """What ``apr demo`` runs out of the box: packaged weights, trained, whose heads are not handed the target."""
    snapshot = demo.choose_policy(None)

    assert snapshot.trained and "packaged checkpoint" in snapshot.label
    assert not snapshot.config.env.reveal_target
    assert "given another scene's images" in snapshot.training  # its blind numbers are shown beside its success


def test_a_probe_of_a_runs_initial_weights_reads_the_encoder_it_started_from(run_dir: Path, tmp_path: Path,
                                                                            monkeypatch) -> None:  # fmt: skip
    from apr.reproduce import probe

    encoded = []
    real_encode = probe.encode
    monkeypatch.setattr(probe, "encode", lambda agent, scenes: encoded.append(agent) or real_encode(agent, scenes))
    args = probe.ProbeArgs(source=f"initial:{run_dir}", train_scenes=4, heldout_scenes=2, labels=("object_map",),
                           readouts=("linear",), out=tmp_path / "out", cache=tmp_path / "cache", threads=2)  # fmt: skip
    path = probe.run(args)
    assert path == tmp_path / "out" / f"initial-{run_dir.name}" / "probe.json"
    assert json.loads(path.read_text())[0]["checkpoint"] == f"initial:{run_dir}"
    trained = policies.load_policy(run_dir)
    fresh = policies.starting_agent(trained.config)
    probed = encoded[0].encoder.state_dict()
    assert all(torch.equal(value, fresh.encoder.state_dict()[name]) for name, value in probed.items())
    assert not all(torch.equal(value, trained.agent.encoder.state_dict()[name]) for name, value in probed.items())
