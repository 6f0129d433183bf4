"""The import rule estimator <- hardware <- twin <- bench, checked on the source of every module.

Each package may import the standard library, the packages below it, and the third-party
libraries listed for it; anything else (an upward import, MuJoCo in a driver, pyserial in the
twin) fails here, including imports hidden inside functions.
"""

import ast
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

ALLOWED = {
    "estimator": {"estimator", "numpy", "cv2", "scipy", "numba"},
    "hardware": {"estimator", "hardware", "numpy", "cv2", "serial"},
    "twin": {"estimator", "hardware", "twin", "numpy", "cv2", "scipy", "mujoco", "pyrender", "trimesh", "OpenGL"},
}


def imported_roots(path: Path) -> set[str]:
    roots = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_its_layer_allows(package):
    files = sorted((REPO / package).rglob("*.py"))
    assert files, f"package {package}/ has no modules"
    violations = []
    for path in files:
        for root in imported_roots(path) - set(sys.stdlib_module_names) - {"__future__"}:
            if root not in ALLOWED[package]:
                violations.append(f"{path.relative_to(REPO)} imports {root}")
    assert not violations, "layering violated:\n" + "\n".join(violations)


def test_the_checker_sees_imports_inside_functions(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f():\n    import mujoco\n    from twin.physics import x\n")
    assert imported_roots(module) == {"mujoco", "twin"}
