"""Layering contracts of the house style, checked on the source: math packages do no I/O; h5py only in store/,
pxr only in usd/, OpenImageIO only in environment/io.py (and image output helpers), click only in cli.py."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "bakery"
MATH_PACKAGES = ["sphere", "sh", "irradiance", "brdf", "reflection"]
RESTRICTED = {"h5py": ["store"], "pxr": ["usd"], "click": ["cli.py"]}


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def sources():
    return sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("package", MATH_PACKAGES)
def test_math_packages_import_only_numpy_scipy_and_bakery_math(package):
    folder = PACKAGE / package
    if not folder.is_dir():
        pytest.skip(f"bakery/{package} does not exist yet")
    allowed = {"numpy", "scipy", "math", "functools", "dataclasses", "typing", "__future__", "bakery", "warnings",
               "collections", "itertools", "enum", "abc"}
    for path in folder.rglob("*.py"):
        extra = imported_modules(path) - allowed
        assert not extra, f"{path.relative_to(PACKAGE)} imports {sorted(extra)}"


@pytest.mark.parametrize("module,homes", RESTRICTED.items())
def test_restricted_imports_stay_in_their_package(module, homes):
    for path in sources():
        relative = path.relative_to(PACKAGE).as_posix()
        if module in imported_modules(path):
            assert any(relative == home or relative.startswith(home + "/") for home in homes), (
                f"{relative} imports {module}; only {homes} may")
