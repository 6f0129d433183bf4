"""The import rule estimator <- hardware <- twin <- bench, checked on the source of every module.

Each package may import the standard library, the packages below it, and the third-party
libraries listed for it; anything else (an upward import, MuJoCo in a driver, pyserial in the
twin) fails here, including imports hidden inside functions. Where a lower package mixes
contracts with drivers, the rule goes down to modules: the twin may use ``hardware``'s
contracts and errors, never its drivers (``hardware.valves`` would pull in pyserial).
"""

import ast
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

ALLOWED = {
    "estimator": {"estimator", "numpy", "cv2", "scipy", "numba"},
    "hardware": {"estimator", "hardware", "numpy", "cv2", "serial"},
    "twin": {"estimator", "hardware", "twin", "numpy", "cv2", "scipy", "numba", "mujoco", "pyrender", "trimesh",
             "OpenGL"},
}

# package -> imported package -> the only modules of it that package may import (all others refused).
ALLOWED_MODULES = {
    "twin": {"hardware": {"hardware", "hardware.interfaces", "hardware.errors"}},
}


def imported_names(path: Path) -> set[str]:
    """Absolute dotted names a module imports; ``from a import b`` yields ``a.b`` (b may be a module)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.update(f"{node.module}.{alias.name}" for alias in node.names if alias.name != "*")
            names.add(node.module)
    return names


def imported_roots(path: Path) -> set[str]:
    return {name.split(".")[0] for name in imported_names(path)}


def module_of(name: str, root: Path = REPO) -> str:
    """The longest prefix of ``name`` that is a module under ``root`` (``hardware.interfaces.ValveBank`` ->
    ``hardware.interfaces``); the first component when none is."""
    parts = name.split(".")
    for end in range(len(parts), 1, -1):
        path = root.joinpath(*parts[:end])
        if path.with_suffix(".py").is_file() or (path / "__init__.py").is_file():
            return ".".join(parts[:end])
    return parts[0]


def layering_violations(path: Path, package: str) -> list[str]:
    """What ``path`` (a module of ``package``) imports against the rule, one line each."""
    where = path.relative_to(REPO) if path.is_relative_to(REPO) else path
    names = imported_names(path)
    violations = [f"{where} imports {root}"
                  for root in sorted({n.split(".")[0] for n in names} - set(sys.stdlib_module_names) - {"__future__"})
                  if root not in ALLOWED[package]]
    for imported, allowed in ALLOWED_MODULES.get(package, {}).items():
        modules = {module_of(n) for n in names if n.split(".")[0] == imported}
        violations += [f"{where} imports {module} (only {', '.join(sorted(allowed))} of {imported})"
                       for module in sorted(modules - allowed)]
    return violations


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_its_layer_allows(package):
    files = sorted((REPO / package).rglob("*.py"))
    assert files, f"package {package}/ has no modules"
    violations = [v for path in files for v in layering_violations(path, package)]
    assert not violations, "layering violated:\n" + "\n".join(violations)


@pytest.mark.parametrize(("package", "imported"), [(p, i) for p, rules in ALLOWED_MODULES.items() for i in rules])
def test_the_modules_a_package_may_import_do_not_pull_in_the_others(package, imported):
    # `import hardware` runs hardware/__init__.py: if it imported the drivers, the module rule would be hollow.
    allowed = ALLOWED_MODULES[package][imported]
    violations = []
    for module in sorted(allowed):
        path = REPO.joinpath(*module.split("."))
        path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        assert path.is_file(), f"{module} is allowed for {package} but does not exist"
        inside = {module_of(n) for n in imported_names(path) if n.split(".")[0] == imported}
        violations += [f"{module} imports {m}" for m in sorted(inside - allowed)]
    assert not violations, f"{package} may import {', '.join(sorted(allowed))}, but:\n" + "\n".join(violations)


def test_the_checker_sees_imports_inside_functions(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f():\n    import mujoco\n    from twin.physics import x\n")
    assert imported_roots(module) == {"mujoco", "twin"}


def test_the_checker_refuses_hardware_drivers_in_the_twin(tmp_path):
    module = tmp_path / "m.py"
    module.write_text(
        "import hardware\n"
        "from hardware import ValveBank, errors\n"
        "from hardware.interfaces import ValveBank\n"
        "from hardware.errors import DeviceError\n"
        "def f():\n"
        "    from hardware.valves import SerialValveBank\n"
        "    import hardware.zed\n"
        "    from hardware import emulator\n"
        "    from hardware.protocol import encode\n"
    )
    violations = layering_violations(module, "twin")
    assert [v.split(" imports ")[1].split(" ")[0] for v in violations] == [
        "hardware.emulator", "hardware.protocol", "hardware.valves", "hardware.zed"]
    assert layering_violations(module, "hardware") == []  # the drivers themselves may import each other
