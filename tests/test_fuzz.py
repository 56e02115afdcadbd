"""The readers of user files under fuzzing (slow): PLY, world.yaml, transforms.json and COLMAP models either
parse or give a clear error, in a child process whose peak memory stays under a stated limit."""

import subprocess
import sys
from pathlib import Path

import pytest

MAX_RSS_MB = 2048  # the fuzzing process with torch, numba and pycolmap loaded: ~500 MB measured


@pytest.mark.slow
def test_readers_survive_fuzzing_in_bounded_memory(tmp_path):
    script = Path(__file__).with_name("fuzz_readers.py")
    r = subprocess.run([sys.executable, str(script), "2000", str(tmp_path)], capture_output=True, text=True,
                       timeout=3600)  # fmt: skip
    print(r.stdout)
    assert r.returncode == 0, r.stderr[-4000:]
    words = r.stdout.split()
    assert words[:8] == ["ply:", "ok", "world:", "ok", "transforms:", "ok", "colmap:", "ok"]
    peak_mb = float(words[words.index("peak_rss_mb") + 1])
    print(f"peak RSS of the fuzzing process: {peak_mb:.0f} MB")
    assert peak_mb < MAX_RSS_MB
