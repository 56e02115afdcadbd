"""The run report: ``<workspace>/report.html``, one page that shows what the last run (``m2m run`` / ``m2m demo``)
did and what the workspace holds: every stage's state and line, the pictures the stages wrote, the datasets'
previews, the warnings, where and why a run stopped, and what to do next.

The page is plain HTML with relative links (images, ``<video>`` of the H.264 previews, the files themselves), so
the workspace folder can be moved or zipped and the page opened from disk, no server. Only files that exist are
linked. It is written by :func:`~.pipeline.run_pipeline` after every run, a failed or interrupted one included
(:class:`RunNotes`), and by ``m2m report`` for an existing workspace (from ``pipeline.json`` and the newest
``run_summary.json`` / ``demo_summary.json``).
"""

from __future__ import annotations

import datetime
import html
import importlib.util
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

from .. import __version__
from ..atomic import atomic_write
from ..errors import M2MError
from ..workspace import Workspace
from . import PIPELINE, get_stage
from .base import Log

__all__ = ["RunNotes", "last_run", "write_report"]

KEYFRAMES_SHOWN = 6
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")

STATES = {  # state -> (what the page says, CSS class)
    "ran": ("done", "ok"),
    "earlier": ("done earlier (up to date)", "ok"),
    "recorded": ("done (not part of the last run)", "ok"),
    "skipped": ("skipped", "skip"),
    "failed": ("failed", "bad"),
    "interrupted": ("interrupted", "bad"),
    "not reached": ("not reached (the run stopped before it)", "skip"),
    "not run": ("not run yet", "skip"),
}


# ---- during a run ---------------------------------------------------------------------------------------------
@dataclass
class RunNotes:
    """What the report says of a run while it goes: each stage's summary (``summaries``, the pipeline's own dict),
    the stages found up to date, the WARNING lines logged (a stage logs some it keeps out of its summary)."""

    command: str
    order: list[str]
    _log: Log
    stage: str | None = None
    summaries: dict[str, Any] = field(default_factory=dict)
    done_earlier: list[str] = field(default_factory=list)
    warnings: dict[str, list[str]] = field(default_factory=dict)
    started: str = field(default_factory=lambda: datetime.datetime.now().isoformat(timespec="seconds"))

    def log(self, line: str) -> None:
        if "WARNING" in line and self.stage is not None:
            self.warnings.setdefault(self.stage, []).append(line)
        self._log(line)

    def fields(self) -> dict[str, Any]:
        """The run's facts for its summary (run_summary.json) and the report."""
        return {"command": self.command, "started": self.started, "order": self.order,
                "done_earlier": self.done_earlier, "warnings": self.warnings}  # fmt: skip

    def stopped(self, ws: Workspace, error: BaseException, seconds: float) -> dict[str, Any]:
        """The run's result when ``error`` stopped it in :attr:`stage`; the report is written and the result
        (with "failed": the stage, the error, what to do) returned for the run's summary."""
        if isinstance(error, KeyboardInterrupt):
            why, todo = "interrupted (Ctrl-C or a signal)", "run the same command again: the interrupted stage resumes"
        elif isinstance(error, M2MError) and error.__cause__ is not None and "\n" in str(error):
            # a PipelineError: the stage's own message, then how to go on
            why, todo = str(error.__cause__), str(error).split("\n", 1)[1]
        elif isinstance(error, M2MError):
            why, todo = str(error), f"fix that and run `{self.command} -w {ws.root}` again"
        else:
            why = f"{type(error).__name__}: {error}"
            todo = "an unexpected error, likely a bug: `m2m --debug ...` shows the traceback; please report it"
        stage = self.stage or (self.order[0] if self.order else "")
        index = self.order.index(stage) + 1 if stage in self.order else 0
        failed = {"stage": stage, "index": index, "of": len(self.order), "error": why, "next": todo,
                  "interrupted": isinstance(error, KeyboardInterrupt)}  # fmt: skip
        result = {"workspace": str(ws.root.resolve()), "stages": self.summaries, "seconds": seconds,
                  **self.fields(), "failed": failed}  # fmt: skip
        if write_report(ws, result, quiet=self._log) is not None:
            self._log(f"where and why it stopped: {ws.report_html}")
        return result


# ---- reading the workspace ---------------------------------------------------------------------------------------
def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def last_run(ws: Workspace) -> dict[str, Any]:
    """The newest run summary of the workspace (run_summary.json or demo_summary.json), {} when there is none;
    an older summary without a "command" gets the one its file name says."""
    found = [(p.stat().st_mtime, p) for p in (ws.run_summary, ws.demo_summary) if p.is_file()]
    if not found:
        return {}
    path = max(found)[1]
    run = _read_json(path)
    run.setdefault("command", "m2m demo" if path == ws.demo_summary else "m2m run")
    return run


def _state(name: str, run: dict[str, Any], records: dict[str, Any]) -> str:
    failed = run.get("failed") or {}
    if failed.get("stage") == name:
        return "interrupted" if failed.get("interrupted") else "failed"
    summary = run.get("stages", {}).get(name)
    if summary is not None:
        if isinstance(summary.get("skipped"), str):  # the plan's reason (a stage's own "skipped" counts things)
            return "skipped"
        return "earlier" if name in run.get("done_earlier", ()) else "ran"
    if failed and name in run.get("order", ()):
        return "not reached"
    return "recorded" if name in records else "not run"


def _warnings_in(x: Any) -> Iterator[str]:
    """The warnings a stage's summary holds: "warning" / "advice" / "validation_problems" entries and the WARNING
    parts of its lines."""
    if isinstance(x, dict):
        for k, v in x.items():
            if k == "warning" and isinstance(v, str):
                yield v
            elif k in ("advice", "validation_problems", "warnings") and isinstance(v, list):
                yield from (str(s) for s in v)
            elif k in ("line", "details") or isinstance(v, dict | list):
                yield from _warnings_in(v)
    elif isinstance(x, list):
        for v in x:
            yield from _warnings_in(v)
    elif isinstance(x, str) and "WARNING" in x:
        yield from (part for part in x.split("; ") if "WARNING" in part)


def _key(warning: str) -> str:
    """The words of a warning without its "stage: WARNING:" prefix (one warning is in a log line and a summary)."""
    return warning.split("WARNING", 1)[-1].lstrip(": ").strip()


def _warnings(name: str, summary: dict[str, Any], run: dict[str, Any]) -> list[str]:
    out: dict[str, str] = {}
    for w in [*_warnings_in(summary), *run.get("warnings", {}).get(name, [])]:
        out.setdefault(_key(w), _key(w))
    return list(out.values())


# ---- HTML pieces -----------------------------------------------------------------------------------------------
def _esc(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _href(ws: Workspace, path: Path) -> str | None:
    """``path`` as a link relative to the page (percent-encoded), None when it does not exist or is outside."""
    try:  # not resolved: a linked file inside the workspace stays a path inside it
        rel = Path(os.path.abspath(path)).relative_to(os.path.abspath(ws.root))
    except ValueError:
        return None
    if not path.exists():
        return None
    return _esc(quote(rel.as_posix()) + ("/" if path.is_dir() else ""))


def _link(ws: Workspace, path: Path, text: str | None = None) -> str:
    href = _href(ws, path)
    label = _esc(text if text is not None else path.name)
    return f'<a href="{href}">{label}</a>' if href else label


def _figure(ws: Workspace, path: Path, caption: str, width: int | None = None) -> str:
    """An image (or an H.264 video, with its poster image as the fallback) that links to its file; "" when the
    file is missing."""
    href = _href(ws, path)
    if href is None:
        return ""
    size = f' style="width:{width}px"' if width else ""
    if path.suffix.lower() == ".mp4":
        poster = _href(ws, path.with_name("contact_sheet.png")) or ""
        media = (f'<video controls muted loop preload="metadata"{size}>'
                 f'<source src="{href}" type="video/mp4" onerror="noVideo(this, \'{poster}\')"></video>')  # fmt: skip
    else:
        media = f'<a href="{href}"><img src="{href}" alt="{_esc(caption)}"{size}></a>'
    return f"<figure>{media}<figcaption>{_esc(caption)} ({_link(ws, path, path.name)})</figcaption></figure>"


def _chart(points: list[tuple[float, float]], xlabel: str, ylabel: str, w: int = 360, h: int = 180) -> str:
    """A small inline SVG line chart (no plotting library, no file)."""
    if len(points) < 2:
        return ""
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    sx = lambda x: 40 + (w - 50) * (x - x0) / ((x1 - x0) or 1)
    sy = lambda y: h - 25 - (h - 35) * (y - y0) / ((y1 - y0) or 1)
    line = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in points)
    return (f'<figure><svg width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img">'
            f'<polyline fill="none" stroke="#2a6fdb" stroke-width="2" points="{line}"/>'
            f'<line x1="40" y1="{h - 25}" x2="{w - 10}" y2="{h - 25}" stroke="#888"/>'
            f'<line x1="40" y1="10" x2="40" y2="{h - 25}" stroke="#888"/>'
            f'<text x="2" y="{sy(y1) + 4:.0f}" font-size="10">{y1:.1f}</text>'
            f'<text x="2" y="{sy(y0) + 4:.0f}" font-size="10">{y0:.1f}</text>'
            f'<text x="40" y="{h - 8}" font-size="10">{x0:.1f}</text>'
            f'<text x="{w - 40}" y="{h - 8}" font-size="10">{x1:.1f}</text>'
            f'<text x="{w / 2 - 40:.0f}" y="{h - 2}" font-size="10">{_esc(xlabel)}</text></svg>'
            f"<figcaption>{_esc(ylabel)}</figcaption></figure>")  # fmt: skip


# ---- what each stage shows ---------------------------------------------------------------------------------------
def _keyframes(ws: Workspace) -> list[Path]:
    if not ws.capture_dir.is_dir():
        return []
    frames = sorted(p for p in ws.capture_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if len(frames) <= KEYFRAMES_SHOWN:
        return frames
    return [frames[round(i * (len(frames) - 1) / (KEYFRAMES_SHOWN - 1))] for i in range(KEYFRAMES_SHOWN)]


def _scene_figures(ws: Workspace) -> str:
    curve = _read_json(ws.scene_metrics).get("curve") or []
    number = lambda v: isinstance(v, int | float) and v == v  # a record's value, not None or NaN
    pts = [(c["seconds"] / 60, c["psnr"]) for c in curve if isinstance(c, dict) and number(c.get("seconds"))
           and number(c.get("psnr"))]  # fmt: skip
    return (_figure(ws, ws.scene_dir / "heldout.png", "held-out keyframes, the photo above the render")
            + _chart(pts, "training minutes", "held-out PSNR (dB) while training"))  # fmt: skip


def _object_figures(ws: Workspace, summary: dict[str, Any]) -> str:
    names = list(summary.get("objects") or {})
    if not names and ws.objects_dir.is_dir():
        names = sorted(p.name for p in ws.objects_dir.iterdir() if p.is_dir())
    caption = "{}: its Gaussians beside its mesh, from the same keyframes"
    return "".join(_figure(ws, ws.object_dir(n) / "figure.png", caption.format(n)) for n in names)


def _pictures(ws: Workspace, name: str, summary: dict[str, Any]) -> str:
    """The figures and pictures of stage ``name`` (the datasets have their own section)."""
    if name == "capture":
        return "".join(_figure(ws, p, p.stem, width=200) for p in _keyframes(ws))
    if name == "align":
        return _figure(ws, ws.overlay_png, "the robot base's footprint and axes (x red, y green, z blue) in a "
                       "keyframe, and the robot's outline at its capture joints (yellow) where the keyframes show it: "
                       "is the scene aligned to the robot?")  # fmt: skip
    if name == "scene":
        return _scene_figures(ws)
    if name == "head_view":
        return _figure(ws, ws.head_view_png, "the scene through the calibrated head camera, beside the head photo "
                       "when there is one")  # fmt: skip
    if name == "objects":
        return _object_figures(ws, summary)
    return ""


def _stage_section(ws: Workspace, name: str, state: str, summary: dict[str, Any], record: dict[str, Any],
                   run: dict[str, Any]) -> str:  # fmt: skip
    stage = get_stage(name)
    text, css = STATES[state]
    seconds = f", {record['seconds']:.0f} s" if state in ("ran", "earlier", "recorded") and "seconds" in record else ""
    parts = [f'<section id="{_esc(name)}"><h3>{_esc(name)} <small><code>m2m {_esc(stage.command)}</code> '
             f"{_esc(stage.help)}</small></h3>", f'<p class="{css}">{_esc(text)}{seconds}</p>']  # fmt: skip
    failed = run.get("failed") or {}
    if state in ("failed", "interrupted"):
        parts.append(f'<pre class="bad">{_esc(failed.get("error", ""))}</pre>')
        if record:
            parts.append("<p>The workspace still holds this stage's result of an earlier run:</p>")
    if summary.get("line"):
        parts.append(f'<p class="line">{_esc(summary["line"])}</p>')
    if summary.get("details"):
        parts.append("<ul>" + "".join(f"<li>{_esc(d)}</li>" for d in summary["details"]) + "</ul>")
    pictures = _pictures(ws, name, summary) if state not in ("skipped", "not run") else ""
    if pictures:
        parts.append(f'<div class="figures">{pictures}</div>')
    return "".join(parts) + "</section>"


def _datasets(ws: Workspace, generate: dict[str, Any]) -> str:
    folders = sorted(p.parent.parent for p in ws.datasets_dir.glob("*/meta/info.json")) if ws.datasets_dir.is_dir() \
        else []  # fmt: skip
    if not folders:
        return ""
    by_folder = {Path(t.get("dataset", "")).name: (task, t) for task, t in (generate.get("tasks") or {}).items()}
    rows = []
    for d in folders:
        task, t = by_folder.get(d.name) or (d.name, _read_json(d / "summary.json"))
        facts = []
        if "episodes" in t:
            facts.append(f"{t['episodes']} episodes, {t.get('frames', '?')} frames")
        if "success_rate" in t:
            facts.append(f"scripted success {100 * t['success_rate']:.0f} % of {t.get('attempts', '?')} attempts")
        if t.get("validation_problems"):
            facts.append(f"{len(t['validation_problems'])} validation problem(s)")
        media = _figure(ws, d / "preview.mp4", "the first episodes, cameras side by side") + _figure(
            ws, d / "contact_sheet.png", "first / middle / last frame of each episode"
        )
        rows.append(f"<section><h3>{_esc(task)}</h3><p>{_esc('; '.join(facts))} — {_link(ws, d, d.name + '/')} "
                    f"({_link(ws, d / 'meta' / 'info.json', 'meta/info.json')})</p>"
                    f'<div class="figures">{media}</div></section>')  # fmt: skip
    return '<h2 id="datasets">Datasets (LeRobot)</h2>' + "".join(rows)


def _policies(ws: Workspace, records: dict[str, Any]) -> str:
    """Trained policies and their evaluations (run on their own, not by ``m2m run``), and the sim-to-real bench."""
    parts = []
    for folder, kind, pictures in ((ws.policies_dir, "train_policy", ("loss_curve.png",)),
                                   (ws.evals_dir, "eval_policy", ("rollout.mp4", "contact_sheet.png"))):  # fmt: skip
        for d in sorted(p for p in folder.glob("*") if (p / "summary.json").is_file()) if folder.is_dir() else []:
            line = (records.get(f"{kind}/{d.name}") or {}).get("summary", {}).get("line") or _read_json(
                d / "summary.json"
            ).get("line", "")
            media = "".join(_figure(ws, d / n, n.split(".")[0].replace("_", " ")) for n in pictures)
            parts.append(f"<section><h3>{_esc(kind.split('_')[0])}: {_esc(d.name)}</h3><p class=\"line\">"
                         f"{_esc(line)}</p><p>{_link(ws, d / 'summary.json', 'summary.json')}</p>"
                         f'<div class="figures">{media}</div></section>')  # fmt: skip
    bench = ws.evals_dir / "sim2real.md"
    if bench.is_file():
        parts.append(f"<section><h3>sim-to-real bench</h3><p>{_link(ws, bench)}</p>"
                     f"<pre>{_esc(bench.read_text(encoding='utf-8', errors='replace'))}</pre></section>")  # fmt: skip
    return '<h2 id="policies">Policies and evaluations</h2>' + "".join(parts) if parts else ""


# ---- the page ------------------------------------------------------------------------------------------------
def _next_steps(ws: Workspace, states: dict[str, str], summaries: dict[str, Any], run: dict[str, Any],
                warned: bool) -> list[str]:  # fmt: skip
    """What to do next, most urgent first (plain text; commands in backticks)."""
    root, failed = ws.root, run.get("failed") or {}
    out = []
    if failed:
        out.append(f"{failed.get('stage')}: {failed.get('next', '')}")
    out += [f"{n} was skipped: {summaries[n].get('skipped')}" for n, s in states.items() if s == "skipped"]
    if warned:
        out.append("read the warnings above, and look at the pictures of the stages they name")
    rest = [n for n, s in states.items() if s == "not run"]
    if rest and not failed:
        out.append(f"`m2m run -w {root}` runs the stages not run yet: {', '.join(rest)}")
    done = {n for n, s in states.items() if s in ("ran", "earlier", "recorded")}
    if "world" in done and importlib.util.find_spec("mirage2matter.commands.view") is not None:
        out.append(f"look at the twin in a browser: `m2m view -w {root}`")
    made = lambda folder, file="summary.json": folder.is_dir() and any(folder.glob(f"*/{file}"))
    if made(ws.datasets_dir, "meta/info.json") and not made(ws.policies_dir):
        out.append(f"train a policy on the datasets: `m2m train-policy -w {root}`, then run it in the twin: `m2m "
                   f"eval-policy -w {root}` (docs: guides/policies.md)")  # fmt: skip
    elif made(ws.policies_dir) and not made(ws.evals_dir):
        out.append(f"run the policy in the twin: `m2m eval-policy -w {root}` (docs: guides/policies.md)")
    return out


def _header(ws: Workspace, run: dict[str, Any]) -> str:
    failed = run.get("failed") or {}
    if not run:
        status, css = "no run summary yet: the stages as pipeline.json records them", "skip"
    elif failed:
        word = "interrupted" if failed.get("interrupted") else "stopped"
        status = f"{word} at {failed.get('stage')} (stage {failed.get('index')} of {failed.get('of')})"
        css = "bad"
    else:
        status, css = "finished", "ok"
    when = f", started {run['started']}" if run.get("started") else ""
    took = f", {run['seconds'] / 60:.1f} min" if isinstance(run.get("seconds"), int | float) else ""
    command = f"<code>{_esc(run.get('command', ''))}</code> " if run.get("command") else ""
    head = (f"<h1>{_esc(ws.root.resolve().name)}: run report</h1><p>{command}<span class=\"{css}\">"
            f"{_esc(status)}</span>{_esc(when + took)}</p>")  # fmt: skip
    if failed:
        name = _esc(failed.get("stage"))
        head += (f'<div class="box bad"><h2>Where and why it stopped</h2><p>stage <a href="#{name}">{name}</a> '
                 f'(<code>m2m {_esc(_command_of(failed.get("stage")))}</code>):</p>'
                 f'<pre>{_esc(failed.get("error", ""))}</pre><p>{_esc(failed.get("next", ""))}</p></div>')  # fmt: skip
    return head


def _command_of(name: Any) -> str:
    try:
        return get_stage(str(name)).command
    except Exception:  # a summary naming a stage this version does not have
        return str(name)


STYLE = """body{font:15px/1.45 system-ui,sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}
h1{margin-bottom:.2em} h3 small{font-weight:normal;color:#666;font-size:.8em} code{background:#f2f2f2;padding:0 3px}
table{border-collapse:collapse;width:100%} td,th{border-bottom:1px solid #ddd;padding:4px 6px;text-align:left}
td{vertical-align:top} td:nth-child(2){white-space:nowrap}
.ok{color:#17702e} .bad{color:#b3261e} .skip{color:#777} .box{border:2px solid;padding:0 1em;margin:1em 0}
pre{white-space:pre-wrap;background:#f7f7f7;padding:.5em} .figures{display:flex;flex-wrap:wrap;gap:12px}
figure{margin:0;max-width:100%} figure img,figure video{max-width:min(100%,540px);border:1px solid #ccc}
figcaption{font-size:.85em;color:#555} section{border-top:1px solid #eee;margin-top:1em}
.line{font-family:ui-monospace,monospace;font-size:.9em}"""

# a video the browser cannot play is replaced by its poster image, linked to the file
SCRIPT = """function noVideo(source, poster) {
  const video = source.parentElement, link = document.createElement('a');
  link.href = source.getAttribute('src');
  if (poster) { const img = document.createElement('img'); img.src = poster; link.appendChild(img); }
  else { link.textContent = 'the video (this browser cannot play it)'; }
  video.replaceWith(link);
}"""


def render_report(ws: Workspace, run: dict[str, Any]) -> str:
    """The page for ``run`` (a run's result or summary; {} for none) over the workspace's records."""
    records = _read_json(ws.record_file)
    names = [s.name for s in PIPELINE]
    states = {n: _state(n, run, records) for n in names}
    summaries = {n: (records.get(n, {}).get("summary") if states[n] not in ("skipped",) else None)
                 or run.get("stages", {}).get(n) or {} for n in names}  # fmt: skip
    warnings = [(n, w) for n in names for w in _warnings(n, summaries[n], run)]
    stopped = (run.get("failed") or {}).get("error", "")
    rows = "".join(
        f'<tr><td><a href="#{_esc(n)}">{_esc(n)}</a></td><td class="{STATES[s][1]}">{_esc(STATES[s][0])}</td>'
        f'<td>{_esc(stopped if s in ("failed", "interrupted") else summaries[n].get("line", ""))}</td></tr>'
        for n, s in states.items())  # fmt: skip
    steps = _next_steps(ws, states, summaries, run, bool(warnings))
    files = [_link(ws, p) for p in (ws.config_file, ws.record_file, ws.run_summary, ws.demo_summary) if p.exists()]
    body = [
        _header(ws, run),
        "<h2>What to do next</h2><ul>" + "".join(f"<li>{_esc(s)}</li>" for s in steps or ["nothing"]) + "</ul>",
        "<h2>Warnings</h2>" + ("<ul>" + "".join(f'<li><a href="#{_esc(n)}">{_esc(n)}</a>: {_esc(w)}</li>'
                                                for n, w in warnings) + "</ul>" if warnings else "<p>none</p>"),
        f"<h2>Stages</h2><table><tr><th>stage</th><th>state</th><th>result</th></tr>{rows}</table>",
        *(_stage_section(ws, n, states[n], summaries[n], records.get(n) or {}, run) for n in names),
        _datasets(ws, summaries["generate"]),
        _policies(ws, records),
        f"<h2>Files</h2><p>{' · '.join(files)}</p>",
        f"<footer><p class=\"skip\">written by m2m {_esc(__version__)} at "
        f"{_esc(datetime.datetime.now().isoformat(timespec='seconds'))}; <code>m2m report -w {_esc(ws.root)}</code> "
        "writes it again</p></footer>",
    ]  # fmt: skip
    title = _esc(f"{ws.root.resolve().name}: run report")
    return (f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{title}</title>'
            f"<style>{STYLE}</style><script>{SCRIPT}</script></head><body>{''.join(body)}</body></html>\n")  # fmt: skip


def write_report(ws: Workspace, run: dict[str, Any] | None = None, quiet: Log | None = None) -> Path | None:
    """Write ``<workspace>/report.html`` atomically for ``run`` (default: the newest run summary); its path.
    With ``quiet`` (a log), a failure to write is logged there and None returned: the report never hides the
    run's own result or error."""
    try:
        page = render_report(ws, last_run(ws) if run is None else run)
        ws.root.mkdir(parents=True, exist_ok=True)
        with atomic_write(ws.report_html, "w", encoding="utf-8") as f:
            f.write(page)
    except Exception as e:
        if quiet is None:
            raise
        quiet(f"the run report was not written: {type(e).__name__}: {e}")
        return None
    return ws.report_html
