"""Each setting has one owner (DESIGN.md section 4): a Config field's distinctive default is written once in src.

Read from the source: every number a dataclass Config (or Options / Spec) field defaults to, and every place that
writes a default by hand - a function parameter's default, another dataclass field's default, an argparse
``default=``, a keyword argument named after a setting given that setting's number (``fps=10``: the setting passed
by hand). A distinctive number (see ``distinctive``) written as a default in more than one place is a mirror: the
others must reference the owner (``EpisodeSpec.fps``, ``EpisodeSpec().size``) or take its section. Different
settings that happen to share a number are listed in ``SHARED``, each with why.
"""

import ast
import sys
from collections import defaultdict
from pathlib import Path

import pytest

import mirage2matter

PKG = Path(mirage2matter.__file__).parent

# Dataclasses whose fields are settings: the stages' ``Config`` and the libraries' *Config / *Options / *Spec (and the
# episode randomisation). Records (EpisodeData, Attempt, RunStats, ...) are data, not settings.
SETTING_CLASS_SUFFIXES = ("Config", "Options", "Spec", "Randomization")


def distinctive(v) -> bool:
    """A number that names one setting when written as a default, not a neutral value. Neutral: bools and None
    (not numbers here); integers below 8 (off / on, counts of one or two, small multipliers - 0, 1, 2, 4 - are
    everywhere and mean nothing alone); the floats 0, 0.5, 1, 2 and anything below 0.01 in size (tolerances,
    epsilons). Everything else (224, 10, 50, 200, 0.06, 1e3, ...) is somebody's choice and has one owner."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    return isinstance(v, int) and abs(v) >= 8


# (file under src/mirage2matter, the field / parameter / flag, the number): a different setting that happens to
# share the number of another one. Keep it short: a mirror of a setting does not belong here.
SHARED = {
    ("export/spec.py", "gop", 10),  # H.264 keyframe interval (frames), not the control rate
    ("stages/eval_policy.py", "episodes", 50),  # episodes evaluated, not the demonstrations generated
    ("video.py", "crf", 20),  # rollout / preview videos' quality, not the datasets' (VideoOptions)
    ("objects/matting.py", "max_gaussians", 60000),  # the matting pass's model, not the object's splat
    ("objects/splat.py", "crop_margin_px", 12),  # pixels, not a count of views or curve points
    ("objects/support.py", "min_cluster_points", 12),  # SfM points in an object's cluster
    ("sample/handeye_capture.py", "views", 12),  # hand-eye calibration images, not curve points
    ("policy/augment.py", "hue_bands", 12),  # colour bands of the hue augmentation
    ("viewer/config.py", "thumbnail_px", 96),  # the viewer's thumbnails, not the policy's input
}

# Mirrors found by this test in code outside the change that introduced it (issue 66: the episode settings), each
# to become a reference to its owner there; ``test_known_mirrors_are_still_there`` makes the list shrink as they go.
KNOWN = {
    ("bench/train.py", "curve_points", 12),  # budget.py's (the trainer object, issue 66 part 3)
    ("gaussians/train.py", "max_gaussians", 1_000_000),  # CappedStrategy's and TrainConfig's
    ("gaussians/dataset.py", "holdout_every", 8),  # the scene stage's (and objects/splat.py's)
    ("objects/splat.py", "holdout_every", 8),
    ("policy/data.py", "image_size", 96),  # PolicyTrainConfig's
    ("policy/model.py", "hidden", 256),  # PolicyModelConfig mirrors PolicyTrainConfig's network
    ("policy/model.py", "keypoints", 32),
    ("policy/model.py", "widths", 16),
    ("policy/model.py", "widths", 32),
    ("policy/model.py", "widths", 64),
    ("sample/render.py", "width", 640),  # the sample maker's SampleConfig
    ("sample/render.py", "height", 480),
}


def _numbers(node: ast.AST) -> list:
    """The numbers a default expression writes: a constant, -constant, a tuple / list of them, the first argument of
    ``ranged(...)`` / ``field(default=...)``, or what a ``default_factory`` lambda returns (dicts' values too)."""
    if isinstance(node, ast.Constant):
        return [node.value] if isinstance(node.value, int) and not isinstance(node.value, bool) else []
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant):
        return [-v for v in _numbers(node.operand)]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [v for e in node.elts for v in _numbers(e)]
    if isinstance(node, ast.Dict):
        return [v for e in node.values for v in _numbers(e)]
    if isinstance(node, ast.Lambda):
        return _numbers(node.body)
    if isinstance(node, ast.Call):
        name = getattr(node.func, "id", None) or getattr(node.func, "attr", None)
        if name == "ranged" and node.args:
            return _numbers(node.args[0])
        if name == "field":
            return [v for k in node.keywords if k.arg in ("default", "default_factory") for v in _numbers(k.value)]
    return []


def _is_dataclass(node: ast.ClassDef) -> bool:
    for d in node.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        if (getattr(target, "id", None) or getattr(target, "attr", None)) == "dataclass":
            return True
    return False


def _sites():
    """(where "file:line", kind, name, number) of every default written in src, and the set of (file, field, number)
    that are settings' own defaults."""
    sites, settings = [], set()
    for path in sorted(PKG.rglob("*.py")):
        rel = str(path.relative_to(PKG))
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for stmt in tree.body:  # a module's constant (FRAME_PX = 224): a default by another name
            if isinstance(stmt, ast.Assign | ast.AnnAssign) and stmt.value is not None:
                targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
                for t in targets:
                    if isinstance(t, ast.Name) and t.id.isupper() and not t.id.startswith("_"):  # private: an id
                        sites += [(f"{rel}:{stmt.lineno}", "constant", t.id.lower(), v) for v in _numbers(stmt.value)]
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef) and _is_dataclass(node):
                setting = node.name.endswith(SETTING_CLASS_SUFFIXES)
                for stmt in node.body:
                    if isinstance(stmt, ast.AnnAssign) and stmt.value is not None and isinstance(stmt.target, ast.Name):
                        for v in _numbers(stmt.value):
                            sites.append((f"{rel}:{stmt.lineno}", "field", stmt.target.id, v))
                            if setting:
                                settings.add((rel, stmt.target.id, v))
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                a = node.args
                positional = a.posonlyargs + a.args
                pairs = list(zip(positional[len(positional) - len(a.defaults) :], a.defaults, strict=True))
                pairs += [(arg, d) for arg, d in zip(a.kwonlyargs, a.kw_defaults, strict=True) if d is not None]
                for arg, d in pairs:
                    for v in _numbers(d):
                        sites.append((f"{rel}:{d.lineno}", "parameter", arg.arg, v))
            elif isinstance(node, ast.Dict):  # {"fps": 10}: keyword arguments gathered first
                for k, val in zip(node.keys, node.values, strict=True):
                    if isinstance(k, ast.Constant) and isinstance(k.value, str) and isinstance(val, ast.Constant):
                        sites += [(f"{rel}:{val.lineno}", "keyword", k.value, v) for v in _numbers(val)]
            elif isinstance(node, ast.Call):
                is_flag = getattr(node.func, "attr", None) == "add_argument"
                for k in node.keywords:
                    if is_flag and k.arg == "default":
                        flag = next((a.value for a in node.args if isinstance(a, ast.Constant)), "?")
                        name = str(flag).lstrip("-").replace("-", "_")
                        sites += [(f"{rel}:{k.value.lineno}", "argparse", name, v) for v in _numbers(k.value)]
                    elif k.arg and isinstance(k.value, ast.Constant | ast.UnaryOp):
                        sites += [(f"{rel}:{k.value.lineno}", "keyword", k.arg, v) for v in _numbers(k.value)]
    return sites, settings


def _round(v: int) -> bool:
    """10, 50, 200, 1000, 16, 256: numbers many unrelated settings choose (a step count and a layer width both pick
    256); such a number marks a mirror only under the same name. 224, 35, 1500 ...: one setting's number anywhere."""
    return v % 10 == 0 or (v > 0 and v & (v - 1) == 0)


def _mirrors(sites, settings) -> dict[str, list[str]]:
    """{setting: the places writing its default} for every distinctive setting default written in more than one
    place (the KNOWN ones left out, the SHARED ones each a setting of its own)."""
    names = defaultdict(set)  # number -> names of the settings that default to it
    for _, name, v in settings:
        if distinctive(v):
            names[v].add(name)
    groups = defaultdict(list)
    for where, kind, name, v in sites:
        file = where.split(":")[0]
        if not distinctive(v) or v not in names or (file, name, v) in KNOWN:
            continue
        if (file, name, v) in SHARED:
            key = f"{name}={v} in {file}"  # its own setting
        elif kind == "keyword" or _round(v):  # a keyword is a setting passed by hand only under the setting's name
            if name not in names[v]:
                continue
            key = f"{name}={v}"
        else:
            key = f"{v}"
        groups[key].append(f"{where} {kind} {name}={v!r}")
    return {k: sorted(set(p)) for k, p in groups.items() if len(set(p)) > 1}


def test_setting_defaults_are_written_once():
    sites, settings = _sites()
    repeated = _mirrors(sites, settings)
    assert not repeated, "a setting's default written in more than one place (reference its owner instead):\n" + (
        "\n".join(f"{k}:\n  " + "\n  ".join(places) for k, places in sorted(repeated.items()))
    )


def test_known_mirrors_are_still_there():
    """A mirror made a reference leaves KNOWN (and SHARED names only numbers still written)."""
    sites, _ = _sites()
    written = {(where.split(":")[0], name, v) for where, _, name, v in sites}
    assert not (KNOWN | SHARED) - written, f"gone from src, drop from the lists: {sorted((KNOWN | SHARED) - written)}"


def test_the_rule_finds_a_mirror(tmp_path, monkeypatch):
    """The check itself: a second dataclass default of a setting's number and an argparse default are found."""
    src = tmp_path / "pkg"
    src.mkdir()
    (src / "a.py").write_text(
        "from dataclasses import dataclass\n@dataclass\nclass FooConfig:\n    size: int = 321\n    n: int = 1\n"
    )
    (src / "b.py").write_text("def f(size=321, n=1):\n    p.add_argument('--size', default=321)\n")
    monkeypatch.setattr(sys.modules[__name__], "PKG", src)
    sites, settings = _sites()
    assert ("a.py", "size", 321) in settings
    found = sorted((where, kind) for where, kind, _, v in sites if v == 321)
    assert found == [("a.py:4", "field"), ("b.py:1", "parameter"), ("b.py:2", "argparse")]
    with pytest.raises(AssertionError, match="b.py:2 argparse size=321"):
        test_setting_defaults_are_written_once()
