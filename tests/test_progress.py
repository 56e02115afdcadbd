"""Progress a person can read: a tqdm bar on a terminal, plain lines in a log (CI, nohup, a file)."""

import io
import re
import time
from pathlib import Path

import numpy as np

from mirage2matter.progress import MAX_LINE, LineProgress, progress_bar

ROOT = Path(__file__).resolve().parents[1]


# ---- progress in a log --------------------------------------------------------------------------------------
class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _lines(text: str) -> list[str]:
    assert "\r" not in text, "a progress line in a log holds a carriage return"
    lines = text.splitlines()
    assert all(len(line) <= MAX_LINE for line in lines), max(lines, key=len)
    return lines


def test_progress_in_a_log_is_a_line_per_tenth():
    out = io.StringIO()
    bar = progress_bar(total=200, desc="train-policy", unit="step", file=out, interval=3600, dynamic_ncols=True)
    assert isinstance(bar, LineProgress)
    for i in range(200):
        bar.update(1)
        bar.set_postfix(step=i + 1, loss=f"{1 / (i + 1):.4f}", refresh=False)
    bar.close()
    lines = _lines(out.getvalue())
    assert 10 <= len(lines) <= 12, lines  # the start, each tenth (the last one is the end)
    assert lines[0].startswith("train-policy: 0/200 step (0 %)")
    assert lines[-1].startswith("train-policy: 200/200 step (100 %)") and "loss=0.0050" in lines[-1]


def test_progress_in_a_log_without_a_total_writes_every_interval():
    out = io.StringIO()
    items = list(progress_bar((i for i in range(30)), desc="train", file=out, interval=0.05))
    assert items == list(range(30))
    # the iteration sleeps below, so the lines come from the clock: at least one every 0.05 s of ~0.3 s
    out2 = io.StringIO()
    for _ in progress_bar((i for i in range(30)), desc="train", file=out2, interval=0.05):
        time.sleep(0.01)
    lines = _lines(out2.getvalue())
    assert len(lines) >= 3, lines
    assert lines[-1].startswith("train: 30 it,")


def test_progress_over_an_iterable_counts_to_its_length_and_cuts_long_lines():
    out = io.StringIO()
    bar = progress_bar(range(50), desc="evaluation", unit="ep", file=out, leave=False)
    bar.set_postfix_str("x" * 1000)
    assert sum(1 for _ in bar) == 50
    lines = _lines(out.getvalue())
    assert lines[-1].startswith("evaluation: 50/50 ep (100 %)") and lines[-1].endswith("...")


def test_progress_disabled_writes_nothing_and_a_terminal_gets_tqdm():
    from tqdm import tqdm

    out = io.StringIO()
    assert list(progress_bar(range(5), disable=True, file=out)) == list(range(5))
    assert out.getvalue() == ""
    term = _Terminal()
    bar = progress_bar(total=3, desc="x", file=term)
    assert isinstance(bar, tqdm)
    bar.update(3)
    bar.close()
    assert "\r" in term.getvalue()  # a bar redrawn in place, as on a terminal


def test_progress_of_an_evaluation_in_a_log(capsys):
    """A call site end to end: evaluate_policy's progress on a stderr that is not a terminal."""
    from mirage2matter.evaluation import evaluate_policy

    class Env:
        t = 0

        def reset(self, seed=None):
            self.t = 0
            return {"observation.images.head": np.zeros((4, 4, 3), np.uint8)}, {}

        def step(self, action):
            self.t += 1
            return {"observation.images.head": np.zeros((4, 4, 3), np.uint8)}, 0.0, self.t >= 3, False, {}

    summary, _ = evaluate_policy(Env(), lambda obs: np.zeros(2), episodes=20, log=lambda s: None, progress=True)
    lines = _lines(capsys.readouterr().err)
    assert len(lines) >= 5 and lines[-1].startswith("evaluation: 20/20 ep (100 %)")


def test_progress_bars_are_made_only_in_progress_py():
    """The choice between a bar and log lines is in one place: no module but progress.py imports tqdm."""
    pkg = ROOT / "src" / "mirage2matter"
    users = [str(p.relative_to(pkg)) for p in pkg.rglob("*.py")
             if p.name != "progress.py" and re.search(r"^\s*(from tqdm|import tqdm)", p.read_text(), re.M)]  # fmt: skip
    assert not users, f"tqdm used directly (use mirage2matter.progress.progress_bar): {users}"
