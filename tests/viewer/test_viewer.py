"""``m2m view``: the twin in a real headless browser (Chromium via selenium), checked by pixels; a drag sent as
viser's client sends it writes world.yaml under the workspace lock (a second writer meanwhile is refused); an
episode plays to its last frame; the exported HTML opens from a file with no server; bad input gets a clear
message (exit status 2, no traceback)."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time
from io import BytesIO
from pathlib import Path

import numpy as np
import yaml

from fixtures.viewer_workspace import add_dataset
from mirage2matter.cli import main
from mirage2matter.workspace import Workspace

M2M = [sys.executable, "-m", "mirage2matter"]


def _viewer(ws: Path, **cfg):
    from mirage2matter.commands.view import _mover, workspace_inputs
    from mirage2matter.viewer import ViewerConfig
    from mirage2matter.viewer.app import TwinViewer

    w = Workspace(ws)
    inputs = workspace_inputs(w)
    return TwinViewer(inputs, ViewerConfig(port=0, **cfg), on_move=_mover(w) if inputs.world else None,
                      log=lambda _: None)  # fmt: skip


def _shot(driver) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(BytesIO(driver.get_screenshot_as_png())).convert("RGB")).astype(np.int16)


def _wait(cond, timeout: float = 30.0, what: str = "") -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, f"timed out waiting for {what}"
        time.sleep(0.2)


def _settled(driver, timeout: float = 60.0) -> np.ndarray:
    """A screenshot once the picture stopped changing (software WebGL fades the scene in over seconds)."""
    last, t0 = _shot(driver), time.monotonic()
    while time.monotonic() - t0 < timeout:
        time.sleep(1.5)
        im = _shot(driver)
        drawn = (np.abs(im[:, : im.shape[1] // 2] - 255).sum(-1) > 30).mean()  # the left half: no GUI panel
        if _changed(im, last) < 50 and drawn > 0.05:
            return im
        last = im
    return last


def _magenta(im: np.ndarray) -> int:
    """Pixels of the keyframe frustums' colour (255, 40, 200)."""
    r, g, b = im[..., 0], im[..., 1], im[..., 2]
    return int(((r > 200) & (g < 110) & (b > 150) & (b < 245)).sum())


def _changed(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a - b).sum(-1) > 40).sum())


def _drag(url: str, name: str, position, wxyz) -> None:
    """What viser's browser client sends when a gizmo is dragged: start, an update with the new pose, end."""
    import msgspec
    import viser
    import websockets

    async def run() -> None:
        ws_url = url.replace("http://", "ws://")
        # no size limit: the scene's splats arrive in one message, over the client library's 1 MiB default
        async with websockets.connect(ws_url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as conn:
            await asyncio.sleep(0.5)
            for msg in ({"type": "TransformControlsDragStartMessage", "name": name, "owner": ""},
                        {"type": "TransformControlsUpdateMessage", "name": name, "wxyz": [float(x) for x in wxyz],
                         "position": [float(x) for x in position], "owner": ""},
                        {"type": "TransformControlsDragEndMessage", "name": name, "owner": ""}):  # fmt: skip
                await conn.send(msgspec.msgpack.encode(msg))
                await asyncio.sleep(0.2)
            await asyncio.sleep(1.0)

    asyncio.run(run())


def _placement(ws: Path, name: str) -> np.ndarray:
    data = yaml.safe_load((ws / "world" / "world.yaml").read_text())
    item = next(o for o in data.get("objects", []) + data.get("articulated", []) if o["name"] == name)
    return np.asarray(item["placement"]["translation"])


def test_browser_shows_scene_robot_frustums_drag_writes_and_episode_plays(viewer_ws, browser, monkeypatch):
    import mirage2matter.world.compose as compose
    from mirage2matter.stages.transaction import workspace_lock

    v = _viewer(viewer_ws)
    try:
        browser.get(v.url)
        _wait(lambda: browser.find_elements("css selector", "canvas"), what="the viewer's canvas")
        full = _settled(browser)
        layers = {}
        for layer in ("scene", "robot", "keyframes"):
            v.show(layer, False)
            layers[layer] = _changed(full, _settled(browser))
            v.show(layer, True)
        _settled(browser)
        assert _magenta(full) > 200, "the keyframe frustums are not drawn"
        assert layers["scene"] > 5000, layers  # hiding a layer changes the picture where it was drawn
        assert layers["robot"] > 1500, layers
        assert layers["keyframes"] > 200, layers

        # a drag released in the page: world.yaml changes through `m2m world move`'s path, the lock held; a second
        # writer (another process) during that write is refused
        before = _placement(viewer_ws, "banana")
        second = {}
        write = compose.write_world_ply

        def write_while_another_tries(*a, **k):
            second["run"] = subprocess.run([*M2M, "world", "move", "-w", str(viewer_ws), "--name", "croissant",
                                            "--by", "0.01,0,0"], capture_output=True, text=True)  # fmt: skip
            return write(*a, **k)

        monkeypatch.setattr(compose, "write_world_ply", write_while_another_tries)
        node = v.objects["banana"]
        target = np.asarray(node.position) + [0.0, -0.06, 0.0]
        _drag(v.url, "/objects/banana", target, node.wxyz)
        _wait(lambda: len(v.messages) >= 1, what="the drag's write")
        assert "world.yaml saved" in v.messages[-1], v.messages
        np.testing.assert_allclose(_placement(viewer_ws, "banana"), target, atol=1e-6)
        assert not np.allclose(before, target)
        assert second["run"].returncode == 2 and "being written by" in second["run"].stderr, second["run"]
        monkeypatch.setattr(compose, "write_world_ply", write)

        # another writer holds the workspace: the drag is refused, the object goes back, world.yaml is as it was
        holder = subprocess.Popen([sys.executable, "-c", (
            "import sys, time\nfrom mirage2matter.workspace import Workspace\n"
            "from mirage2matter.stages.transaction import workspace_lock\n"
            f"with workspace_lock(Workspace({str(viewer_ws)!r}), 'test holder'):\n"
            "    print('held', flush=True)\n    time.sleep(20)\n")], stdout=subprocess.PIPE, text=True)  # fmt: skip
        try:
            assert holder.stdout.readline().strip() == "held"
            _drag(v.url, "/objects/banana", target + [0.05, 0.0, 0.0], node.wxyz)
            _wait(lambda: len(v.messages) >= 2, what="the refused drag")
        finally:
            holder.kill()
            holder.wait()
        assert "not saved" in v.messages[-1] and "being written by" in v.messages[-1], v.messages
        np.testing.assert_allclose(_placement(viewer_ws, "banana"), target, atol=1e-6)
        np.testing.assert_allclose(node.position, target, atol=1e-6)
        with workspace_lock(Workspace(viewer_ws)):  # and the viewer left no lock behind
            pass

        # an episode, played from the page's Play button to its last frame
        ep = v.load_episode("dataset", "grasp_banana", 2)
        time.sleep(1)
        button = next(b for b in browser.find_elements("css selector", "button") if b.text.strip() == "Play")
        button.click()
        _wait(lambda: v.frame == ep.length - 1 and not v.playing, what="the episode's last frame")
        _wait(lambda: f"frame {ep.length - 1} / {ep.length - 1}" in browser.find_element("tag name", "body").text,
              what="the page showing the last frame")  # fmt: skip
    finally:
        v.close()


def test_export_opens_from_a_file_without_a_server(viewer_ws, browser, tmp_path):
    played = tmp_path / "episode.html"  # an episode exports as the scene's animation
    assert main(["view", "-w", str(viewer_ws), "--export", str(played), "--episode", "grasp_banana:1"]) == 0
    out = tmp_path / "view.html"
    assert main(["view", "-w", str(viewer_ws), "--export", str(out)]) == 0
    assert played.stat().st_size > out.stat().st_size
    html = out.read_text()
    assert "__VISER_EMBED_DATA__" in html and 'src="http' not in html and "playbackPath" not in html.split("<body")[0]
    browser.get(out.as_uri())
    _wait(lambda: browser.find_elements("css selector", "canvas"), what="the exported page's canvas")
    im = _settled(browser)
    assert _magenta(im) > 200  # the keyframe frustums, from the embedded scene alone
    assert int((np.abs(im - im[0, 0]).sum(-1) > 60).sum()) > 20000  # and much more than a blank page


def test_workspace_without_a_world_shows_what_exists_and_names_what_is_missing(viewer_ws, tmp_path, capsys):
    import shutil

    ws = Workspace(viewer_ws)
    shutil.rmtree(ws.world_dir)
    out = tmp_path / "v.html"
    assert main(["view", "-w", str(viewer_ws), "--export", str(out)]) == 0
    text = capsys.readouterr().out
    assert "not there yet: the world" in text and "m2m compose" in text and "train-scene" in text
    assert out.stat().st_size > 100_000


def test_bad_input_is_a_clear_message(viewer_ws, tmp_path, capsys):
    ws = Workspace(viewer_ws)
    with socket.socket() as s:  # a port in use
        s.bind(("127.0.0.1", 0))
        s.listen()
        assert main(["view", "-w", str(viewer_ws), "--port", str(s.getsockname()[1])]) == 2
    assert "in use" in capsys.readouterr().err


    add_dataset(ws, "other_robot", robot_type="ur5e")  # a dataset of another robot
    assert main(["view", "-w", str(viewer_ws), "--export", str(tmp_path / "a.html"), "--episode", "other_robot"]) == 2
    err = capsys.readouterr().err
    assert "recorded with robot 'ur5e'" in err and "Traceback" not in err
    assert main(["view", "-w", str(viewer_ws), "--export", str(tmp_path / "a.html"), "--episode", "nothing:3"]) == 2
    assert "no dataset or evaluation named 'nothing'" in capsys.readouterr().err

    ply = next(ws.world_dir.rglob("gaussians.ply"))  # a corrupt PLY
    ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nend_header\n\x00\x01")
    before = {p: p.stat().st_mtime_ns for p in viewer_ws.rglob("*") if p.is_file()}
    assert main(["view", "-w", str(viewer_ws), "--export", str(tmp_path / "b.html")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("m2m: error:") and str(ply.name) in err and "Traceback" not in err
    after = {p: p.stat().st_mtime_ns for p in viewer_ws.rglob("*") if p.is_file()}
    assert after == before  # the viewer wrote nothing in the workspace
