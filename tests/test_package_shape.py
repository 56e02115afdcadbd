"""The package's shape (DESIGN.md section 4), read from its source: no import circles, workspace paths only in
workspace.py and stages/, robot facts only in robots/, one error base, a thin command line."""

import ast
import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest

import mirage2matter
from mirage2matter.errors import M2MError

PKG = Path(mirage2matter.__file__).parent


def _modules() -> dict[str, Path]:
    mods = {}
    for p in PKG.rglob("*.py"):
        name = ".".join(p.relative_to(PKG.parent).with_suffix("").parts).removesuffix(".__init__")
        mods[name] = p
    return mods


def _rel(p: Path) -> str:
    return str(p.relative_to(PKG))


def _import_graph() -> dict[str, set[str]]:
    """module -> the package's modules it imports, at module level or inside functions (parent packages and
    their children are not edges: importing a.b runs a/__init__ anyway)."""
    mods = _modules()
    graph = {m: set() for m in mods}
    for m, p in mods.items():
        base = m if p.name == "__init__.py" else m.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = base.split(".")
                    target = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                names = [target] + [f"{target}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            graph[m].update(
                n for n in names if n in mods and n != m and not n.startswith(m + ".") and not m.startswith(n + ".")
            )
    return graph


def test_no_import_circles():
    graph = _import_graph()
    cycles, state, stack = [], {}, []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if state.get(v) == 1:
                cycles.append(" -> ".join(stack[stack.index(v) :] + [v]))
            elif v not in state:
                visit(v)
        stack.pop()
        state[u] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import circles:\n" + "\n".join(cycles)


def test_layers_point_one_way():
    """geometry imports nothing of ours but errors and inputs (which import nothing but errors); libraries import
    no stage, command or CLI module."""
    graph = _import_graph()
    upper = ("mirage2matter.stages", "mirage2matter.commands", "mirage2matter.cli", "mirage2matter.__main__")
    assert graph["mirage2matter.inputs"] <= {"mirage2matter.errors"} and not graph["mirage2matter.errors"]
    for m, deps in graph.items():
        if m.startswith("mirage2matter.geometry"):
            leaves = {"mirage2matter.errors", "mirage2matter.inputs"}
            assert deps <= {d for d in deps if d.startswith("mirage2matter.geometry")} | leaves, m
        if not m.startswith(upper):
            bad = sorted(d for d in deps if d.startswith(upper))
            assert not bad, f"{m} (a library) imports {bad}"


# the workspace's folders and the files only the workspace knows (m2m.yaml is not among them: a sample has one too)
WORKSPACE_NAMES = {
    "capture", "sfm", "calib", "scene", "objects", "world", "datasets", "pipeline.json", "run_summary.json",
    "demo_summary.json", "sim3_sfm_to_base.json", "cameras_base.json", "points_base.npy", "colors_base.npy",
    "handeye.json", "head_view.json", "task_summary.json",
}  # fmt: skip


def test_workspace_paths_are_built_only_in_workspace_py_and_stages():
    """``<something> / "calib"`` and friends appear nowhere else: below the stages, code gets folders and
    typed objects (``Workspace`` owns the layout)."""
    found = []
    for p in PKG.rglob("*.py"):
        rel = _rel(p)
        if rel == "workspace.py" or rel.startswith("stages/"):
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            parts = []
            if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
                parts = [node.right]
            elif isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "joinpath":
                parts = node.args
            for part in parts:
                if isinstance(part, ast.Constant) and part.value in WORKSPACE_NAMES:
                    found.append(f"{rel}:{node.lineno} / {part.value!r}")
    assert not found, "workspace paths built outside workspace.py and stages/:\n" + "\n".join(found)


# Numbers that are Franka Panda facts (home pose, gains, limits, reach, gripper geometry).
PANDA_NUMBERS = {0.785, 2.356, 1.571, 4500, 3500, 450, 350, 87, 2.175, 2.61, 7.5, 12.5, 0.333, 0.316, 0.384, 0.088,
                 0.107, 0.1034, 0.1123, 0.072, 0.012}  # fmt: skip
ROBOT_WORD = re.compile(r"franka|panda(?!s)", re.IGNORECASE)  # "pandas" (the parquet metadata) is not the robot


def _docstring_nodes(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
    return ids


def test_robot_facts_live_in_robots():
    """No Panda name, link or number outside robots/: the rest of the package asks a RobotSpec."""
    found = []
    for p in PKG.rglob("*.py"):
        rel = _rel(p)
        if rel.startswith("robots/"):
            continue
        tree = ast.parse(p.read_text())
        docs = _docstring_nodes(tree)
        for node in ast.walk(tree):
            text = None
            if isinstance(node, ast.Constant) and id(node) not in docs:
                if isinstance(node.value, str):
                    text = node.value
                    if text == "hand":
                        found.append(f"{rel}:{node.lineno} the link name 'hand'")
                elif isinstance(node.value, int | float) and not isinstance(node.value, bool):
                    if node.value in PANDA_NUMBERS and rel.startswith(("sim/", "world/", "calib/", "export/")):
                        found.append(f"{rel}:{node.lineno} the number {node.value}")
            elif isinstance(node, ast.Name):
                text = node.id
            elif isinstance(node, ast.Attribute):
                text = node.attr
            elif isinstance(node, ast.FunctionDef | ast.ClassDef):
                text = node.name
            if text and ROBOT_WORD.search(text):
                found.append(f"{rel}:{node.lineno} {text[:60]!r}")
    assert not found, "robot facts outside robots/:\n" + "\n".join(found)


def test_every_error_class_derives_from_the_one_base():
    orphans = []
    for info in pkgutil.walk_packages([str(PKG)], prefix="mirage2matter."):
        if info.name.startswith("mirage2matter.sample.render") or info.name.endswith("__main__"):
            continue  # imports Genesis
        module = importlib.import_module(info.name)
        for name, obj in inspect.getmembers(module, inspect.isclass):
            if obj.__module__ == info.name and issubclass(obj, Exception) and not issubclass(obj, M2MError):
                orphans.append(f"{info.name}.{name}")
    assert not orphans, f"exceptions outside M2MError: {orphans}"


@pytest.mark.parametrize("limit", [400])
def test_thin_command_line_and_short_stage_functions(limit):
    assert len((PKG / "cli.py").read_text().splitlines()) <= limit
    long = []
    for p in (PKG / "stages").glob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.FunctionDef) and node.end_lineno - node.lineno + 1 > 100:
                long.append(f"{_rel(p)}:{node.lineno} {node.name}")
    assert not long, f"stage functions over 100 lines: {long}"
