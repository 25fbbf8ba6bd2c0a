"""pld-slam ablate: suites, cell keys, resuming, failed cells, the paper's table, the Dask path."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest
from click.testing import CliRunner
from evo.tools import file_interface
from processes import ends_within

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.errors import ConfigError
from pld_slam.report import cells
from pld_slam.report.ablation import prepare_ablation, write_report
from pld_slam.report.cells import CellSpec, cell_key, execute_cell, plan_cells, sequence_identity, unique_labels
from pld_slam.report.runner import run_cells
from pld_slam.report.store import ROW_COLUMNS, cell_dir, is_finished, read_cell, recorded_rows
from pld_slam.report.suite import BUILTIN_SUITES, Suite, Variant, load_suite
from pld_slam.report.tables import paper_table, to_csv, to_latex, to_markdown
from pld_slam.synth.writer import write_sequence
from pld_slam_cli.main import cli

TWO_VARIANTS = Suite("two", "", (Variant("lines", ("lines.enabled=true",)),
                                 Variant("points", ("lines.enabled=false",))))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """An 8-frame 320x240 synthetic sequence: each cell runs in a few seconds."""
    folder = tmp_path_factory.mktemp("tiny") / "tiny_static"
    write_sequence(folder, "static", 8, size=(320, 240), seed=3)
    return folder


def write_suite(path, text):
    path.write_text(text)
    return str(path)


# --- suites -------------------------------------------------------------------------------

def test_every_builtin_suite_loads_with_its_variants_in_file_order():
    for name in BUILTIN_SUITES:
        suite = load_suite(name)
        assert suite.variants and suite.description
    assert [v.name for v in load_suite("table1").variants] == ["without", "grid", "llg", "grid+llg"]
    assert load_suite("lines").variants[0].overrides == ("lines.enabled=false",)


def test_a_variant_naming_an_unknown_key_is_an_error_naming_the_file_and_variant(tmp_path):
    path = write_suite(tmp_path / "bad.yaml",
                       "variants:\n  ok: {dynamic.grid: false}\n  typo: {dynamic.gird: true}\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: variant typo: .*unknown key dynamic\.gird"):
        load_suite(path)


def test_a_variant_with_a_bad_value_or_a_suite_without_variants_is_an_error(tmp_path):
    with pytest.raises(ConfigError, match="variant v: .*dynamic.grid must be true or false"):
        load_suite(write_suite(tmp_path / "value.yaml", "variants:\n  v: {dynamic.grid: 3}\n"))
    with pytest.raises(ConfigError, match="needs a 'variants' mapping"):
        load_suite(write_suite(tmp_path / "empty.yaml", "description: nothing\n"))
    with pytest.raises(ConfigError, match="no such suite"):
        load_suite("no_such_suite")


def test_variants_that_would_write_the_same_cell_folder_are_refused_naming_both(tiny, tmp_path):
    suite = write_suite(tmp_path / "clash.yaml", "variants:\n  a/b: {}\n  c: {}\n  a_b: {lines.enabled: false}\n")
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["ablate", str(tiny), "--suite", suite, "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert result.output == ("error: variants 'a/b' and 'a_b' of suite clash would write the same cell folder "
                             "(cells/SEQUENCE/a_b); rename one\n")
    assert not (out / "ablation.json").exists()


def test_bow_without_a_vocabulary_is_refused_before_anything_runs(tiny):
    with pytest.raises(ConfigError, match="bow needs a vocabulary"):
        plan_cells([open_sequence(tiny)], load_suite("loop"))


# --- the cell key -------------------------------------------------------------------------

def test_the_cell_key_changes_with_the_config_the_frames_and_the_sequence(tiny):
    identity = sequence_identity(open_sequence(tiny))
    config = load_config()
    key = cell_key(identity, config, None)
    assert cell_key(identity, load_config(), None) == key
    assert cell_key(identity, load_config(overrides=["dynamic.grid=false"]), None) != key
    assert cell_key(identity, config, 5) != key
    assert cell_key({**identity, "frames": identity["frames"] - 1}, config, None) != key


def test_a_cells_key_depends_on_its_variant_and_the_common_overrides(tiny):
    sequence = open_sequence(tiny)
    lines, points = plan_cells([sequence], TWO_VARIANTS)
    assert lines.key != points.key
    assert plan_cells([sequence], TWO_VARIANTS)[0].key == lines.key
    assert plan_cells([sequence], TWO_VARIANTS, ["points.n_features=500"])[0].key != lines.key


def test_sequences_of_the_same_name_are_labelled_by_their_folders_then_numbered():
    def seq(name, root):
        return SimpleNamespace(name=name, root=root)

    sequences = [seq("synth_dynamic", "/a/seed0"), seq("synth_dynamic", "/a/seed1"), seq("06", "/k/06"),
                 seq("synth_dynamic", "/b/seed0")]
    assert unique_labels(sequences) == ["seed0", "seed1", "06", "seed0-2"]


# --- running, resuming, failing -----------------------------------------------------------

def test_a_rerun_reuses_finished_cells_and_redoes_an_unfinished_one(tiny, tmp_path):
    cells = prepare_ablation(tmp_path, [tiny], TWO_VARIANTS)
    assert run_cells(tmp_path, cells, workers=2) == cells
    assert all(is_finished(tmp_path, spec) for spec in cells)
    rows = recorded_rows(tmp_path)
    assert [(r["variant"], r["status"]) for r in rows] == [("lines", "ok"), ("points", "ok")]
    assert rows[0]["frames"] == 8 and rows[0]["ate_rmse_m"] < 0.1
    for spec, row in zip(cells, rows, strict=True):  # each cell's evo result, what evo_res compares
        saved = file_interface.load_res_file(cell_dir(tmp_path, spec) / "ate.zip")
        assert saved.stats["rmse"] == pytest.approx(row["ate_rmse_m"], rel=1e-6)  # from the TUM file
        assert saved.info["est_name"] == f"{spec.sequence}_{spec.variant}"
    (cell_dir(tmp_path, cells[1]) / "cell.json").unlink()  # as if killed during this cell
    finished_at = (cell_dir(tmp_path, cells[0]) / "cell.json").stat().st_mtime_ns
    again = prepare_ablation(tmp_path, [tiny], TWO_VARIANTS)
    assert run_cells(tmp_path, again, workers=2) == [cells[1]]
    assert (cell_dir(tmp_path, cells[0]) / "cell.json").stat().st_mtime_ns == finished_at
    assert read_cell(tmp_path, cells[1])["ate_rmse_m"] == rows[1]["ate_rmse_m"]  # deterministic


def test_a_failing_cell_is_recorded_with_its_reason_and_the_others_go_on(tiny, tmp_path):
    missing = tmp_path / "missing_vocabulary.npz"
    suite = Suite("s", "", (Variant("bad", ("loop.detector=bow", f"loop.vocabulary={missing}")),
                            Variant("good", ())))
    cells = prepare_ablation(tmp_path, [tiny], suite)
    run_cells(tmp_path, cells, workers=1)
    bad, good = recorded_rows(tmp_path)
    assert bad["status"] == "failed" and "missing_vocabulary.npz" in bad["reason"]
    assert good["status"] == "ok" and good["ate_rmse_m"] is not None
    assert not is_finished(tmp_path, cells[0])  # failed cells run again next time


def test_a_cell_over_its_time_limit_fails_saying_so(tiny, tmp_path):
    (spec,) = plan_cells([open_sequence(tiny)], Suite("s", "", (Variant("v", ()),)))
    outcome = execute_cell(spec, timeout=0.3)  # no run of 8 frames, imports included, ends in 0.3 s
    assert outcome.status == "failed" and outcome.reason == "time limit of 0.3 s reached"


GREEDY_RUN = """
import subprocess, sys
ballast = "import sys; ballast = b'x' * (300 << 20); sys.stdin.read()"  # held until its parent is gone
subprocess.Popen([sys.executable, "-c", ballast], stdin=subprocess.PIPE).wait()
"""
"""A run that stays small itself while its child takes 300 MiB, as a run's front end would."""

NOWHERE = CellSpec("key", "sequence", "variant", "/nowhere", "{}\n")


def test_a_cell_whose_run_with_its_children_exceeds_its_memory_limit_fails_saying_so(monkeypatch):
    if not cells.memory_limit_enforced():
        pytest.skip("the memory limit needs Linux's /proc")
    monkeypatch.setattr(cells, "run_command", lambda spec, run_dir, config_path: [sys.executable, "-c", GREEDY_RUN])
    start = time.monotonic()
    outcome = execute_cell(NOWHERE, timeout=10, max_memory_mb=100)  # the time limit ends it if the memory's does not
    assert outcome.status == "failed" and outcome.reason == "memory limit of 100 MiB reached"
    assert time.monotonic() - start < 5


def test_a_cells_run_dies_with_the_process_that_started_it(tmp_path):
    if not cells.memory_limit_enforced():
        pytest.skip("needs Linux (prctl, /proc)")
    pid_file = tmp_path / "run.pid"
    run = f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); time.sleep(60)"
    worker = subprocess.Popen([sys.executable, "-c", (
        "import sys; from pld_slam.report import cells; "
        f"cells.run_command = lambda *_: [sys.executable, '-c', {run!r}]; "
        f"cells.execute_cell(cells.CellSpec('key', 'sequence', 'variant', '/nowhere', '{{}}'))")],
        env={**os.environ, "TMPDIR": str(tmp_path)})  # where the killed cell's scratch stays
    deadline = time.monotonic() + 60
    while not (pid_file.is_file() and pid_file.read_text()) and time.monotonic() < deadline:
        time.sleep(0.05)
    run_pid = int(pid_file.read_text())
    worker.kill()  # as a Dask worker killed mid-cell
    worker.wait()
    assert ends_within(run_pid, 5.0)


def test_ablate_killed_half_way_and_started_again_redoes_no_finished_cell(tiny, tmp_path):
    suite_path = write_suite(tmp_path / "two.yaml",
                             "variants:\n  a: {lines.enabled: true}\n  b: {lines.enabled: false}\n")
    out = tmp_path / "out"
    command = [sys.executable, "-m", "pld_slam_cli", "ablate", str(tiny), "--suite", suite_path,
               "--out", str(out), "--workers", "1"]
    first = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True,
                             env={**os.environ, "TMPDIR": str(tmp_path)})  # where the killed cell's scratch stays
    deadline = time.monotonic() + 120
    while not list(out.glob("cells/*/*/cell.json")) and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    assert first.poll() is None, first.stderr.read()  # still running its second cell
    os.killpg(first.pid, signal.SIGKILL)
    first.wait()
    (done,) = out.glob("cells/*/*/cell.json")
    finished = done.read_text()
    second = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    assert "2 cells: 1 run (0 failed), 1 reused" in second.stdout
    assert re.search(r"^cell 1/1 synth_static / [ab]: ok, 8 frames, ATE \d\.\d{4} m, \d+\.\d s$", second.stdout, re.M)
    assert done.read_text() == finished
    assert len(list(out.glob("cells/*/*/cell.json"))) == 2


# --- the table ----------------------------------------------------------------------------

def row(sequence, variant, t, r, status="ok"):
    return {**dict.fromkeys(ROW_COLUMNS), "sequence": sequence, "variant": variant, "status": status,
            "ate_rmse_m": t, "ate_rot_rmse_deg": r}


ROWS = [row("00", "a", 0.5, 2.0), row("00", "b", 0.4, 3.0),
        row("01", "a", 0.2, 1.0), row("01", "b", 0.3, 0.5),
        row("02", "a", 0.1, 0.1), row("02", "b", None, None, status="failed")]


def test_the_paper_table_bolds_the_best_of_each_metric_per_row_and_means_the_complete_rows():
    table = paper_table(ROWS, ["00", "01", "02"], ["a", "b"])
    best = table.best()
    assert best.loc["00"].tolist() == [False, True, True, False]  # a t, a R, b t, b R
    assert best.loc["01"].tolist() == [True, False, False, True]
    assert table.mean_over == 2  # 02 failed under b: the mean covers 00 and 01 only
    assert table.values.loc["mean", ("a", "t")] == pytest.approx(0.35)
    assert table.values.loc["mean", ("b", "R")] == pytest.approx(1.75)
    markdown = to_markdown(table)
    assert "| 00 | 0.5000 | **2.000** | **0.4000** | 3.000 |" in markdown
    assert "| 02 | **0.1000** | **0.100** | fail | fail |" in markdown
    assert "| mean (2) |" in markdown
    assert to_csv(table).splitlines()[0] == "sequence,a t,a R,b t,b R"


def test_values_equal_as_shown_are_both_bold():
    table = paper_table([row("00", "a", 0.12341, 1.0), row("00", "b", 0.12339, 2.0)], ["00"], ["a", "b"])
    assert table.best().loc["00"].tolist() == [True, True, True, False]


def test_the_latex_table_is_a_balanced_booktabs_tabular_with_a_column_per_cell(tmp_path):
    latex = to_latex(paper_table(ROWS, ["00", "01", "02"], ["a", "b"]))
    body = [line for line in latex.splitlines() if line.endswith(r"\\")]
    assert latex.count("{") == latex.count("}")
    assert re.search(r"\\begin\{tabular\}\{lrrrr\}", latex) and latex.rstrip().endswith(r"\end{tabular}")
    spans = [line.count("&") + 1 + sum(int(n) - 1 for n in re.findall(r"\\multicolumn\{(\d+)\}", line))
             for line in body]
    assert spans == [5] * len(body)
    assert [line.split(" & ")[0] for line in body][2:] == ["00", "01", "02", "mean (2)"]
    assert r"\textbf{0.4000}" in latex and r"\toprule" in latex and r"\bottomrule" in latex
    if shutil.which("pdflatex"):  # where LaTeX is installed, it must compile as is
        document = r"\documentclass{article}\usepackage{booktabs}\begin{document}" + latex + r"\end{document}"
        (tmp_path / "table.tex").write_text(document)
        compiled = subprocess.run(["pdflatex", "-interaction=nonstopmode", "table.tex"], cwd=tmp_path,
                                  capture_output=True)
        assert compiled.returncode == 0


def test_report_rebuilds_tables_and_plots_from_the_recorded_cells(tiny, tmp_path):
    cells = prepare_ablation(tmp_path, [tiny], TWO_VARIANTS)
    run_cells(tmp_path, cells, workers=2)
    write_report(tmp_path)
    first = (tmp_path / "table.md").read_text()
    for name in ("table.md", "table.tex", "table.csv", "results.csv"):
        (tmp_path / name).unlink()
    result = CliRunner().invoke(cli, ["ablate", "--report", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "table.md").read_text() == first
    assert (tmp_path / "plots" / "ate.png").is_file()
    assert (tmp_path / "plots" / "trajectories_synth_static.png").is_file()
    assert (tmp_path / "results.csv").read_text().splitlines()[0] == ",".join(ROW_COLUMNS)


def test_report_on_a_folder_that_is_no_ablation_says_so(tmp_path):
    result = CliRunner().invoke(cli, ["ablate", "--report", str(tmp_path)])
    assert result.exit_code == 2 and "not the output folder of pld-slam ablate" in result.output


@pytest.mark.parametrize("content, problem", [
    (b"{", "not valid JSON"),
    (b"[1, 2]", "expected an object with the keys " + ", ".join(ROW_COLUMNS)),
    (b'{"sequence": "s", "variant": "v"}', "expected an object with the keys "),
    (b'{"sequence": "caf\xe9"}', "not a text file (byte 17 is not UTF-8)"),
])
def test_report_with_a_corrupt_cell_json_is_an_error_naming_it_before_writing_anything(tmp_path, content, problem):
    (tmp_path / "ablation.json").write_text(json.dumps({"suite": "x", "description": "", "variants": ["v"],
                                                        "sequences": ["s"], "sequence_dirs": ["/s"]}))
    cell = tmp_path / "cells" / "s" / "v" / "cell.json"
    cell.parent.mkdir(parents=True)
    cell.write_bytes(content)
    result = CliRunner().invoke(cli, ["ablate", "--report", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {cell}") and problem in result.output and result.output.count("\n") == 1
    assert not (tmp_path / "results.csv").exists()


@pytest.mark.parametrize("content", ['{"suite": "x"}', '{"variants": "v", "sequences": ["s"]}', "[]"])
def test_report_with_a_malformed_ablation_json_is_an_error_naming_it(tmp_path, content):
    (tmp_path / "ablation.json").write_text(content)
    result = CliRunner().invoke(cli, ["ablate", "--report", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {tmp_path / 'ablation.json'}: expected ")
    assert result.output.count("\n") == 1


# --- Dask ---------------------------------------------------------------------------------

def test_a_dask_cluster_gives_the_same_results_as_the_local_pool_cell_for_cell(tiny, tmp_path):
    distributed = pytest.importorskip("distributed")
    local_cells = prepare_ablation(tmp_path / "local", [tiny], TWO_VARIANTS)
    run_cells(tmp_path / "local", local_cells, workers=2)
    dask_cells = prepare_ablation(tmp_path / "dask", [tiny], TWO_VARIANTS)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        run_cells(tmp_path / "dask", dask_cells, scheduler=cluster.scheduler_address, max_memory_mb=4000)
    local, remote = recorded_rows(tmp_path / "local"), recorded_rows(tmp_path / "dask")
    assert [r["status"] for r in remote] == ["ok", "ok"]
    for a, b in zip(local, remote, strict=True):
        assert (a["sequence"], a["variant"], a["config_hash"]) == (b["sequence"], b["variant"], b["config_hash"])
        assert a["ate_rmse_m"] == b["ate_rmse_m"] and a["frames"] == b["frames"]
    assert json.loads((cell_dir(tmp_path / "dask", dask_cells[0]) / "summary.json").read_text())["frames"] == 8
