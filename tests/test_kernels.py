"""Every numba kernel is compiled before a run's first frame, and a run compiles nothing more (`pld_slam.kernels`).

Both tests run in a fresh interpreter, so that no kernel was compiled by another test.
"""

import json
import os
import subprocess
import sys

import pytest

from pld_slam.datasets import open_sequence
from pld_slam.synth import write_sequence

WARM_UP_EVERY_MODULE = """
import importlib, json, pkgutil
import pld_slam
from pld_slam.kernels import compile_kernels, kernel_signatures
for module in pkgutil.walk_packages(pld_slam.__path__, prefix="pld_slam."):
    importlib.import_module(module.name)
compile_kernels()
print(json.dumps(kernel_signatures()))
"""

RUN_AFTER_THE_WARM_UP = """
import json, sys
from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.kernels import compile_kernels, kernel_signatures
from pld_slam.system import System
compile_kernels()
before = kernel_signatures()
config = load_config(overrides=["system.prefetch=false", "optimize.global_ba=true"])
result = System(open_sequence(sys.argv[1]), config).run()
print(json.dumps({"before": before, "after": kernel_signatures(), "keyframes": len(result.insertions),
                  "global_ba": result.global_ba is not None}))
"""


def last_json_line(script: str, *args: str, env: dict | None = None) -> dict:
    """What ``script`` run by a fresh interpreter printed last, as JSON."""
    completed = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, check=True,
                               env=env)
    return json.loads(completed.stdout.strip().splitlines()[-1])


def test_every_kernel_the_package_declares_is_compiled_by_the_warm_up(tmp_path):
    """With an empty cache, so that kernels called only by other kernels compile too (from the
    cache they come inside their callers and show no signature of their own)."""
    signatures = last_json_line(WARM_UP_EVERY_MODULE, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})
    assert len(signatures) >= 10
    assert [name for name, count in signatures.items() if count == 0] == []


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("kernels") / "dynamic"
    write_sequence(out, "dynamic", 16, (320, 240), seed=1)
    return open_sequence(out)


def test_a_run_after_the_warm_up_compiles_no_kernel_for_new_argument_types(sequence):
    """The front end runs in the same process (no prefetch), so every kernel the run calls shows there."""
    report = last_json_line(RUN_AFTER_THE_WARM_UP, str(sequence.root))
    assert report["global_ba"] and report["keyframes"] >= 3
    assert report["after"] == report["before"]
