"""tactile6d's subpackages are layers: a module imports only from its own layer and the ones below it
(each subpackage's ``__init__`` says what it holds), and no module lives outside a subpackage."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "tactile6d"
# Lowest first.
LAYERS = ("core", "data", "runtime", "sim", "perception", "estimation", "evaluation", "cli")


def imported_modules(path: Path) -> set[str]:
    """Dotted tactile6d modules (or packages) that ``path`` imports, at module or function level."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tactile6d"):
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("tactile6d"))
    return out


def layer_of(dotted: str) -> str | None:
    parts = dotted.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def modules():
    return sorted(p for p in PACKAGE.rglob("*.py") if p.parent != PACKAGE)


@pytest.mark.parametrize("path", modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_only_its_own_layer_and_lower(path):
    own = path.relative_to(PACKAGE).parts[0]
    assert own in LAYERS, f"{path.relative_to(PACKAGE)} is in no layer of {LAYERS}"
    upward = sorted(m for m in imported_modules(path) if layer_of(m) and LAYERS.index(layer_of(m)) > LAYERS.index(own))
    assert not upward, f"{path.relative_to(PACKAGE)} ({own}) imports from a higher layer: {upward}"


def test_every_module_is_in_a_layer():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert top == ["__init__.py"], f"modules outside a subpackage: {top}"
    assert sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()) == sorted(LAYERS)


@pytest.mark.parametrize("layer", LAYERS)
def test_each_layer_says_what_it_holds(layer):
    doc = ast.get_docstring(ast.parse((PACKAGE / layer / "__init__.py").read_text()))
    assert doc and "imports" in doc, f"tactile6d/{layer}/__init__.py: a docstring saying what it holds and imports"


def test_a_violation_is_seen(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from tactile6d.estimation.estimator import Estimator\n")
    assert any(layer_of(m) == "estimation" for m in imported_modules(bad))
