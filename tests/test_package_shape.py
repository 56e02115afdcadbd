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
    no stage, benchmark, command or CLI module."""
    graph = _import_graph()
    upper = (
        "mirage2matter.stages",
        "mirage2matter.bench",
        "mirage2matter.commands",
        "mirage2matter.cli",
        "mirage2matter.__main__",
    )  # the benchmarks time the stages' own code
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


# Packages from the bottom up (issue 66): each imports only packages on its own level or below. Top-level modules
# count as packages. One level may hold several packages (they may import one another; the circle test keeps them
# apart at module level).
PACKAGE_LEVELS = [
    {"errors", "inputs", "atomic", "progress", "processes", "fingerprint", "video", "configs", "ray_cluster", "lazy"},
    {"geometry"},
    {"robots"},
    {"gaussians", "sfm", "capture", "calib", "objects"},
    {"world"},
    {"sim"},
    {"render", "export"},
    {"env"},
    {"datagen"},
    {"policy", "evaluation", "eval_workers"},
    {"workspace", "viewer"},
    {"sample"},  # the sample maker: a tool; nothing of the runtime imports it
    {"stages"},
    {"bench"},  # every benchmark (they time the stages' own code)
    {"commands"},
    {"cli", "__main__"},
]


def _package(module: str) -> str:
    return module.split(".")[1] if "." in module else module


def test_packages_import_only_downwards():
    level = {p: i for i, ps in enumerate(PACKAGE_LEVELS) for p in ps}
    packages = {_package(m) for m in _modules() if m != "mirage2matter"}
    assert packages <= set(level), f"packages with no place in PACKAGE_LEVELS: {sorted(packages - set(level))}"
    wrong = sorted(
        f"{_package(m)} -> {_package(d)} ({m} imports {d})"
        for m, deps in _import_graph().items()
        if m != "mirage2matter"
        for d in deps
        if level[_package(d)] > level[_package(m)]
    )
    assert not wrong, "imports against the package order:\n" + "\n".join(wrong)


def test_the_runtime_does_not_import_the_sample_maker():
    """``mirage2matter.sample`` makes test captures; only the commands that make or inspect them import it."""
    users = sorted({_package(m) for m, deps in _import_graph().items() for d in deps if _package(d) == "sample"})
    assert set(users) <= {"sample", "commands"}, users


# Third-party modules slow to import (or needing a display, a GPU, a service) or optional (sam2, fast_simplification:
# a clear message without them): the only ones loaded inside functions, so that `m2m --help` and the stages' configs
# load none of them. OpenGL picks its platform when first imported: only after Genesis has chosen EGL.
HEAVY_THIRD_PARTY = {
    "torch", "genesis", "pycolmap", "ray", "open3d", "viser", "mujoco", "cv2", "av", "numba", "ompl", "coacd",
    "gsplat", "trimesh", "skimage", "scipy", "pyarrow", "matplotlib", "selenium", "PIL", "lerobot", "plyfile",
    "fsspec", "pandas", "manifold3d", "mkdocs", "tqdm", "sam2", "fast_simplification", "gymnasium", "OpenGL",
}  # fmt: skip


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> str:
    base = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    if not node.level:
        return node.module or ""
    parts = base.split(".")
    return ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))


def _top_level_imports(module: str, path: Path) -> tuple[set[str], set[str]]:
    """(our modules, heavy third-party packages) a module imports when it is imported (TYPE_CHECKING aside)."""
    ours, heavy = set(), set()

    def walk(body):
        for n in body:
            if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test):
                continue
            if isinstance(n, ast.If | ast.Try):
                walk(n.body + n.orelse + [s for h in getattr(n, "handlers", []) for s in h.body])
            elif isinstance(n, ast.Import):
                heavy.update({a.name.split(".")[0] for a in n.names} & HEAVY_THIRD_PARTY)
                ours.update(a.name for a in n.names if a.name.startswith("mirage2matter"))
            elif isinstance(n, ast.ImportFrom):
                target = _resolve(module, path, n)
                heavy.update({target.split(".")[0]} & HEAVY_THIRD_PARTY)
                if target.startswith("mirage2matter"):
                    ours.update({target} | {f"{target}.{a.name}" for a in n.names})

    walk(ast.parse(path.read_text()).body)
    return ours, heavy


# Ours that import modules by name at import (importlib), which the ast cannot follow: PipelineConfig is built from
# every stage's Config.
LOADS_EVERY_STAGE = {"mirage2matter.stages.pipeline"}

# Ours slow to import though they load no heavy third-party package: the generation library (datagen/ brings ~30 of
# our modules, its renderers, export, workers; and with it the generate stage and the benchmarks), which `m2m --help`
# and the commands that do not generate load none of (tests/test_cli.py checks).
HEAVY_OURS = {"mirage2matter.datagen"}


def _loads_heavy() -> dict[str, bool]:
    """Our module -> whether importing it loads a heavy third-party package or one of ``HEAVY_OURS`` (through any of
    ours it imports)."""
    mods = _modules()
    table = {m: _top_level_imports(m, p) for m, p in mods.items()}
    memo: dict[str, bool] = {}

    def heavy(m: str, stack: frozenset = frozenset()) -> bool:
        if m not in memo:
            ours, third = table[m]
            chain = {".".join(d.split(".")[:i]) for d in ours for i in range(2, d.count(".") + 2)}
            memo[m] = (
                bool(third)
                or m in LOADS_EVERY_STAGE | HEAVY_OURS
                or any(heavy(d, stack | {m}) for d in chain if d in mods and d not in stack | {m})
            )
        return memo[m]

    return {m: heavy(m) for m in mods}


def _lazy_names(path: Path) -> set[str] | None:
    """A package's module ``__getattr__`` hands out names on first use (loading torch): those names, else None."""
    tree = ast.parse(path.read_text())
    getattr_assigned = any(
        isinstance(n, ast.Assign) and any(isinstance(x, ast.Name) and x.id == "__getattr__" for x in n.targets)
        for n in tree.body
    )
    if not getattr_assigned and not any(isinstance(n, ast.FunctionDef) and n.name == "__getattr__" for n in tree.body):
        return None
    bound = {a.asname or a.name for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom) for a in n.names}
    return {"*"} - bound  # any name not bound at import is lazy


def test_imports_inside_functions_only_for_heavy_modules():
    """An import inside a function defers a cost: it must name a heavy third-party package, or a module of ours
    that loads one (or a name a package hands out lazily). Anything else belongs at the top of the file. Fails on
    ``from ..errors import M2MError`` written inside a function."""
    mods, heavy = _modules(), _loads_heavy()
    light = []
    for m, p in mods.items():
        for fn in ast.walk(ast.parse(p.read_text())):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for n in ast.walk(fn):
                if isinstance(n, ast.Import):
                    names = [a.name for a in n.names]
                    if any(x.split(".")[0] in HEAVY_THIRD_PARTY for x in names):
                        continue
                    targets = [x for x in names if x.startswith("mirage2matter")]
                elif isinstance(n, ast.ImportFrom):
                    target = _resolve(m, p, n)
                    if target.split(".")[0] in HEAVY_THIRD_PARTY:
                        continue
                    if not target.startswith("mirage2matter"):
                        light.append(f"{_rel(p)}:{n.lineno} {target}")
                        continue
                    lazy = _lazy_names(mods[target]) if target in mods else None
                    subs = [f"{target}.{a.name}" for a in n.names if f"{target}.{a.name}" in mods]
                    lazy_hit = lazy is not None and any(
                        a.name not in {x.rsplit(".", 1)[1] for x in subs} and a.name not in _bound(mods[target])
                        for a in n.names
                    )
                    if lazy_hit:
                        continue
                    targets = [target, *subs]
                else:
                    continue
                chain = {".".join(t.split(".")[:i]) for t in targets for i in range(2, t.count(".") + 2)}
                if not any(heavy.get(t, False) for t in chain):
                    light.append(f"{_rel(p)}:{n.lineno} {', '.join(targets)}")
    assert not light, f"{len(light)} imports inside functions of light modules (move them up):\n" + "\n".join(light)


def _bound(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = {a.asname or a.name for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom) for a in n.names}
    return out | {n.name for n in tree.body if isinstance(n, ast.FunctionDef | ast.ClassDef)}


# Each engine in one package: the rest of the code asks that package (sfm.load_model_points, robots.kinematics,
# sim.scene.ensure_genesis), so that a version change of an engine is one package's concern.
ENGINE_OWNERS = {"pycolmap": "sfm", "mujoco": "robots", "genesis": "sim"}


def test_each_engine_is_imported_by_one_package():
    wrong = []
    for m, p in _modules().items():
        for n in ast.walk(ast.parse(p.read_text())):
            names = [a.name for a in n.names] if isinstance(n, ast.Import) else []
            if isinstance(n, ast.ImportFrom) and not n.level:
                names = [n.module or ""]
            for name in names:
                owner = ENGINE_OWNERS.get(name.split(".")[0])
                if owner is not None and _package(m) != owner:
                    wrong.append(f"{_rel(p)}:{n.lineno} imports {name} (only {owner}/ does)")
    assert not wrong, "\n".join(wrong)


def test_no_lazy_name_is_its_own_submodule_s_name():
    """A package's lazy name that is also its submodule's name (render's ``composite``) hands out the module once any
    code has imported the submodule directly: which one a caller got depended on import order."""
    import importlib

    for init in sorted(PKG.rglob("__init__.py")):
        if "_LAZY = " not in init.read_text():
            continue
        package = ".".join(init.parent.relative_to(PKG.parent).parts)
        lazy = importlib.import_module(package)._LAZY
        clashes = [name for name, sub in lazy.items() if name == sub]
        assert not clashes, f"{package}: lazy names that are their submodule's name: {clashes}"
