"""Layering contracts of the house style, checked on the source: math packages do no I/O and import only bakery
math; each third-party package with side effects or a heavy import has one home (OpenImageIO: environment/io.py,
pxr: usd/, h5py: store/, embreex: capture/, dask/distributed: pipeline/executors.py, click and rich: cli.py), and
so do hashing and atomic file replacement (bakery/files.py)."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "bakery"
MATH_PACKAGES = ["sphere", "sh", "irradiance", "brdf", "reflection"]
#: bakery modules the math packages may import (themselves, the conventions and the error types).
MATH_BAKERY_IMPORTS = {"bakery", *(f"bakery.{name}" for name in MATH_PACKAGES), "bakery.conventions", "bakery.errors"}
RESTRICTED = {
    "OpenImageIO": ["environment/io.py"],
    "pxr": ["usd"],
    "h5py": ["store"],
    "embreex": ["capture"],
    "dask": ["pipeline/executors.py"],
    "distributed": ["pipeline/executors.py"],
    "click": ["cli.py"],
    "rich": ["cli.py"],
    "hashlib": ["files.py"],  # content hashes: bakery.files.sha256_bytes / sha256_file / stable_hash
}


def imported_names(path: Path, source: str | None = None) -> set[str]:
    """Full dotted names of every module ``path`` imports (anywhere, also inside functions); ``from a import b``
    yields ``a.b`` as well as ``a`` (b may be a module); relative imports are resolved against the package.
    ``source`` replaces the file's text (for testing the checker)."""
    tree = ast.parse(path.read_text() if source is None else source, filename=str(path))
    package = ["bakery", *path.relative_to(PACKAGE).parent.parts]
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            names.add(module)
            names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def imported_modules(path: Path) -> set[str]:
    """Top-level packages ``path`` imports."""
    return {name.split(".")[0] for name in imported_names(path)}


def sources():
    return sorted(PACKAGE.rglob("*.py"))


def _math_folder(package: str) -> Path:
    folder = PACKAGE / package
    if not folder.is_dir():
        pytest.skip(f"bakery/{package} does not exist yet")
    return folder


@pytest.mark.parametrize("package", MATH_PACKAGES)
def test_math_packages_import_only_numpy_scipy_and_bakery_math(package):
    allowed = {"numpy", "scipy", "math", "functools", "dataclasses", "typing", "__future__", "bakery", "warnings",
               "collections", "itertools", "enum", "abc"}
    for path in _math_folder(package).rglob("*.py"):
        extra = imported_modules(path) - allowed
        assert not extra, f"{path.relative_to(PACKAGE)} imports {sorted(extra)}"


def _bakery_module(name: str) -> str:
    """The bakery package or top-level module a dotted name lies in: ``bakery.sphere.cubemap.x`` → ``bakery.sphere``."""
    return ".".join(name.split(".")[:2])


@pytest.mark.parametrize("package", MATH_PACKAGES)
def test_math_packages_import_only_bakery_math(package):
    for path in _math_folder(package).rglob("*.py"):
        bakery_imports = {_bakery_module(n) for n in imported_names(path) if n == "bakery" or n.startswith("bakery.")}
        extra = bakery_imports - MATH_BAKERY_IMPORTS
        assert not extra, f"{path.relative_to(PACKAGE)} imports {sorted(extra)}; math packages may import only " \
                          f"{sorted(MATH_BAKERY_IMPORTS)}"


@pytest.mark.parametrize("module,homes", RESTRICTED.items())
def test_restricted_imports_stay_in_their_home(module, homes):
    for path in sources():
        relative = path.relative_to(PACKAGE).as_posix()
        if module in imported_modules(path):
            assert any(relative == home or relative.startswith(home + "/") for home in homes), (
                f"{relative} imports {module}; only {homes} may")


def test_atomic_replacement_has_one_home():
    """Files are replaced only through :func:`bakery.files.atomic_replace` (temp file, fsync, rename)."""
    for path in sources():
        relative = path.relative_to(PACKAGE).as_posix()
        calls = [node.lineno for node in ast.walk(ast.parse(path.read_text()))
                 if isinstance(node, ast.Attribute) and node.attr == "replace"
                 and isinstance(node.value, ast.Name) and node.value.id == "os"]
        assert relative == "files.py" or not calls, (
            f"{relative}:{calls[0] if calls else ''} calls os.replace; use bakery.files.atomic_replace")


def test_the_checker_sees_nested_relative_and_from_imports():
    source = "def f():\n    import h5py\n    from bakery import operator_cache\n    from ..store import format\n"
    names = imported_names(PACKAGE / "sphere" / "example.py", source)
    assert {"h5py", "bakery.operator_cache", "bakery.store.format"} <= names
    assert {_bakery_module(n) for n in names if n.startswith("bakery.")} - MATH_BAKERY_IMPORTS == {
        "bakery.operator_cache", "bakery.store"}
