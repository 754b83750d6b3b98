"""dvc.yaml must list, for each stage, the code it runs: its module and every tactile6d module it
imports (directly or through other tactile6d modules), so that editing that code re-runs the stage."""

import ast
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent


def tactile6d_imports(path: Path, seen: set[Path] | None = None) -> set[Path]:
    """Files of tactile6d imported by ``path``, transitively (module-level and function-level imports)."""
    seen = set() if seen is None else seen
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tactile6d"):
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names if a.name.startswith("tactile6d")]
        for name in names:
            parts = name.split(".")
            # Importing tactile6d.a.b runs tactile6d/a/__init__.py first.
            packages = [REPO / Path(*parts[:i]) / "__init__.py" for i in range(2, len(parts))]
            rel = Path(*parts)
            for candidate in (*packages, REPO / rel.with_suffix(".py"), REPO / rel / "__init__.py"):
                if candidate.is_file() and candidate not in seen:
                    seen.add(candidate)
                    tactile6d_imports(candidate, seen)
    return seen


def stages():
    spec = yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"]
    return [(name, body.get("do", body)) for name, body in spec.items()]


def stage_module(stage: dict) -> str:
    """The module a stage runs (``python -m stages.<module> ...``): most stages run their namesake, the
    distractor stages the per-object stage they repeat."""
    words = stage["cmd"].split()
    return words[words.index("-m") + 1].removeprefix("stages.")


@pytest.mark.parametrize("name,stage", stages(), ids=[n for n, _ in stages()])
@pytest.mark.slow
def test_code_deps_match_imports(name, stage):
    module = REPO / "stages" / f"{stage_module(stage)}.py"
    assert module.is_file(), f"stage {name} runs {stage['cmd']!r}: no module {module.relative_to(REPO)}"
    # Python imports the package first: stages/__init__.py, and what it imports, runs before every stage.
    package = REPO / "stages" / "__init__.py"
    imported = tactile6d_imports(module) | tactile6d_imports(package)
    needed = {str(p.relative_to(REPO)) for p in imported} - {"tactile6d/__init__.py"}
    needed |= {str(module.relative_to(REPO)), str(package.relative_to(REPO))}
    deps = {d for d in stage["deps"] if d.endswith(".py")}
    assert needed <= deps, f"{name}: code it imports but does not list as deps: {sorted(needed - deps)}"
    assert deps <= needed, f"{name}: deps it does not import: {sorted(deps - needed)}"


def test_no_stage_imports_another():
    for module in (REPO / "stages").glob("*.py"):
        for node in ast.walk(ast.parse(module.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                assert not node.module.startswith("stages"), f"{module.name} imports {node.module}"
