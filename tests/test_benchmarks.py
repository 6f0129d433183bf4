"""Every benchmark script starts from any folder, against the installed packages, shadowing none of them.

Run as a script, a file's own folder comes first on sys.path: a script named like a package
(``benchmarks/estimator.py``) would be imported in its place. The scripts are named apart from
the packages instead of patching sys.path.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((REPO / "benchmarks").glob("*.py"))
PACKAGES = {"estimator", "hardware", "twin", "bench", "models", "tests", "benchmarks"}


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.name for s in SCRIPTS])
def test_benchmark_script_starts(script, tmp_path):
    result = subprocess.run([sys.executable, str(script), "--help"], cwd=tmp_path, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert "usage:" in result.stdout


def test_no_script_shadows_a_package_or_patches_the_import_path():
    assert len(SCRIPTS) >= 5
    assert not {s.stem for s in SCRIPTS} & PACKAGES
    for script in SCRIPTS:
        tree = ast.parse(script.read_text())
        calls = [node for node in ast.walk(tree) if isinstance(node, ast.Attribute) and node.attr == "path"
                 and isinstance(node.value, ast.Name) and node.value.id == "sys"]
        assert not calls, f"{script.name} patches sys.path"


def test_twin_speed_times_another_checkout_in_a_child_process():
    """``twin_speed.py --baseline DIR`` times DIR's twin in a child process (here: this checkout's own)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("twin_speed_under_test", REPO / "benchmarks" / "twin_speed.py")
    twin_speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(twin_speed)
    times = twin_speed.grab_times_of(REPO, ["", "lab"], 2)
    assert set(times) == {"", "lab"}
    assert all(len(v) == 2 and all(t > 0 for t in v) for v in times.values())
    with pytest.raises(SystemExit, match="failed"):
        twin_speed.grab_times_of(REPO / "no-such-checkout", [""], 1)
