"""pld-slam regress: baselines, the tolerance, a worsened run failing, missing data skipped."""

import json

import pytest
from click.testing import CliRunner

from pld_slam.errors import ConfigError, PldSlamError
from pld_slam.report.regress import Verdict, judge, read_baseline, updated_baseline
from pld_slam_cli.main import cli

SYNTHETIC = {"synthetic": "static", "seed": 3, "frames": 10}


def invoke(*args):
    return CliRunner().invoke(cli, ["regress", *map(str, args)])


def write_json(path, content):
    path.write_text(json.dumps(content))
    return path


def test_a_worsened_config_fails_the_check_and_the_same_code_passes(tmp_path, monkeypatch):
    monkeypatch.delenv("PLD_SLAM_DATA", raising=False)
    baseline = write_json(tmp_path / "ci.json", {"cells": [
        {"name": "static", "sequence": SYNTHETIC},
        {"name": "real", "sequence": {"data": "kitti_odometry/sequences/06"}, "ate_rmse_m": 0.2},
    ]})
    work = tmp_path / "work"
    updated = invoke(baseline, "--update", "--out", work)
    assert updated.exit_code == 0, updated.output
    recorded = json.loads(baseline.read_text())["cells"]
    assert recorded[0]["ate_rmse_m"] < 0.05 and recorded[1]["ate_rmse_m"] == 0.2  # skipped: kept

    same = invoke(baseline, "--out", work)
    assert same.exit_code == 0, same.output
    assert "pass" in same.output and "skipped (PLD_SLAM_DATA is not set)" in same.output

    worse = invoke(baseline, "--out", work, "--set", "points.n_features=150", "--set", "lines.enabled=false")
    assert worse.exit_code == 1, worse.output
    assert "worse" in worse.output and "regression: 1 of 2 cells" in worse.output


def test_the_tolerance_is_relative_plus_absolute_and_a_cell_may_carry_its_own():
    tolerance = {"relative": 0.10, "absolute_m": 0.001}
    cell = {"name": "c", "ate_rmse_m": 0.1}
    ok = {"status": "ok", "ate_rmse_m": 0.111}
    assert judge(cell, ok, tolerance).status == "pass"  # allowed 0.1 * 1.1 + 0.001 = 0.111
    assert judge(cell, {**ok, "ate_rmse_m": 0.1115}, tolerance).status == "worse"
    assert judge({**cell, "tolerance": {"relative": 0.5}}, {**ok, "ate_rmse_m": 0.15}, tolerance).status == "pass"
    failed = judge(cell, {"status": "failed", "ate_rmse_m": None, "reason": "boom"}, tolerance)
    assert failed.status == "failed" and failed.regressed and failed.note == "boom"
    assert judge({"name": "new"}, ok, tolerance).status == "new"


def test_update_refuses_to_record_a_failed_run():
    baseline = {"cells": [{"name": "c", "sequence": SYNTHETIC, "ate_rmse_m": 0.1}]}
    with pytest.raises(PldSlamError, match="cannot update the baseline: c: boom"):
        updated_baseline(baseline, [Verdict("c", 0.1, None, None, "failed", "boom")])


@pytest.mark.parametrize("content, message", [
    ("{", "not valid JSON"),
    ('{"cells": [{"name": "a"}]}', "cell 1: needs a 'name' and a 'sequence'"),
    ('{"cells": [{"name": "a", "sequence": {"synthetic": "static"}}]}', "needs an integer 'seed' and 'frames'"),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}, "overrides": ["dynamic.gird=true"]}]}',
     r"cell 1 \(a\): .*unknown key dynamic.gird"),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}}, {"name": "a", "sequence": {"path": "/y"}}]}',
     "name 'a' is used twice"),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}, "ate_rmse_m": "0.1"}]}',
     r"cell 1 \(a\): 'ate_rmse_m' must be a finite number >= 0 or null, got '0.1'"),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}, "ate_rmse_m": -1}]}',
     r"cell 1 \(a\): 'ate_rmse_m' must be a finite number >= 0 or null, got -1"),
    ('{"tolerance": {"relative": "10 %"}, "cells": []}', "tolerance: 'relative' must be a finite number >= 0"),
    ('{"tolerance": {"relatve": 0.1}, "cells": []}', "tolerance: unknown key 'relatve' "),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}, "tolerance": {"absolute_m": null}}]}',
     r"cell 1 \(a\): tolerance: 'absolute_m' must be a finite number >= 0, got None"),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}, "overrides": "lines.enabled=false"}]}',
     r"cell 1 \(a\): 'overrides' must be a list of section.key=value strings"),
    ('{"cells": [{"name": "a", "sequence": {"path": "/x"}, "max_frames": "10"}]}',
     r"cell 1 \(a\): 'max_frames' must be a positive integer or null, got '10'"),
    ('{"cells": [{"name": "a", "sequence": {"path": 7}}]}', r"cell 1: the sequence's 'path' must be a string"),
    ('{"cells": [{"name": "a/b", "sequence": {"path": "/x"}}, {"name": "a_b", "sequence": {"path": "/y"}}]}',
     r"cell 2: names 'a/b' and 'a_b' would write the same cell folder \(a_b\); rename one"),
    ('{"cells": [{"name": "a", "sequence": {"synthetic": "stattic", "seed": 0, "frames": 5}}]}',
     "cell 1: unknown synthetic scenario 'stattic'"),
])
def test_a_malformed_baseline_is_an_error_naming_the_file_and_the_cell(tmp_path, content, message):
    path = tmp_path / "base.json"
    path.write_text(content)
    with pytest.raises(ConfigError, match=message):
        read_baseline(path)
    result = invoke(path)
    assert result.exit_code == 2 and "base.json" in result.output


def test_a_baseline_that_is_not_utf8_is_an_error_naming_the_file(tmp_path):
    path = tmp_path / "base.json"
    path.write_bytes('{"description": "caf\u00e9", "cells": []}'.encode("latin-1"))
    with pytest.raises(ConfigError, match=rf"{path}: not a text file \(byte 20 is not UTF-8\)"):
        read_baseline(path)
    result = invoke(path)
    assert result.exit_code == 2 and result.output.startswith(f"error: {path}: not a text file (byte 20 is not UTF-8)")


def test_a_baseline_with_a_byte_order_mark_reads(tmp_path):
    path = tmp_path / "base.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps({"description": "caf\u00e9", "cells": []}).encode("utf-8"))
    assert read_baseline(path)["description"] == "caf\u00e9"


def test_a_baseline_that_cannot_be_read_is_an_error_naming_the_file(tmp_path):
    path = tmp_path / "base.json"
    path.mkdir()
    with pytest.raises(ConfigError, match=f"{path}: cannot read baseline "):
        read_baseline(path)


def test_a_check_where_every_cell_is_skipped_says_nothing_was_checked_and_fails_unless_allowed(
        tmp_path, monkeypatch):
    monkeypatch.delenv("PLD_SLAM_DATA", raising=False)
    baseline = write_json(tmp_path / "ci.json", {"cells": [
        {"name": "real", "sequence": {"data": "kitti_odometry/sequences/06"}, "ate_rmse_m": 0.2}]})
    result = invoke(baseline, "--out", tmp_path / "work")
    assert result.exit_code == 2, result.output
    assert "skipped (PLD_SLAM_DATA is not set)" in result.stdout
    assert result.stderr == (f"error: {baseline}: nothing checked: its 1 cell was skipped (the table says why); "
                             "--allow-skipped accepts that\n")
    allowed = invoke(baseline, "--out", tmp_path / "work", "--allow-skipped")
    assert allowed.exit_code == 0, allowed.output
    assert allowed.stdout.endswith("\nnothing checked (1 skipped)\n")
