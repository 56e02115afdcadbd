"""One process draws the splat layer of every generation worker's episodes, batched (issue 17: GPU generation).

Generation's workers each run physics, planning and the robot layer; on a GPU machine the splat layer is what a
batched gsplat call does best (one call for every episode in flight, every camera: ``SplatWorldBatch``), and a
worker process of its own per episode would leave the GPU idle between its small calls. A :class:`SplatServer`
holds the world once, as a ``SplatWorldBatch`` with one copy (a *slot*) per worker; a worker's hybrid renderer
takes a slot (:class:`RemoteSplatLayer`) and, per frame, sends its parts' physics poses and its cameras; the
server gathers the frames asked for by all slots (waiting ``gather_ms`` at most for the rest), poses and renders
them in one call, and writes each slot's layers into memory that slot's worker reads (no pickling of images).

An episode's per-copy look travels with its start: the objects' scale (``Randomization.object_shrink``) and the
table's texture (``Randomization.table_texture``). Every camera is drawn whole each frame (a static camera is not
drawn over a cached background as ``SplatWorld.render_static_camera`` does): the same frames up to that cache's
approximation at moving parts' outlines.

Protocol (all requests on one queue, each answered on the slot's own pipe): ``("attach", slot)``,
``("episode", slot, object_scale, table_texture)``, ``("frame", slot, poses, viewmats [C,4,4], Ks [C,3,3])`` ->
the layers in the slot's buffer, ``("detach", slot)`` (unanswered); ``None`` stops the server.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
import traceback
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import M2MError
from ..processes import die_with_parent
from .table_texture import TableGaussians

__all__ = ["RemoteSplatLayer", "SplatServer", "SplatServerError", "SplatServerHandle"]

LAYERS = 5  # rgb, alpha, depth per pixel in a slot's buffer


class SplatServerError(M2MError, RuntimeError):
    """The splat server failed, died or has no slot free; the message says which and what to do."""


@dataclass
class SplatServerHandle:
    """What a worker needs to use a running server; picklable into spawned processes (only when they start).

    requests  the server's request queue;  replies  [S] each slot's receiving end;  buffers  [S] each slot's
    float32 [C, H, W, 5] layers;  free  queue of free slot indices;  cameras, size (width, height), pid
    """

    requests: Any
    replies: list
    buffers: list
    free: Any
    cameras: int
    size: tuple[int, int]
    pid: int


class SplatServer:
    """The server process (``with SplatServer(...) as handle:``); see the module docstring.

    parts        the splat layer's files (``env.hybrid.splat_parts``)
    options      per-frame splat settings (``SplatRenderOptions``; its backend picks the device)
    slots        copies of the world: at most this many workers at once
    cameras      cameras per frame (every slot draws as many)
    size         (width, height) of every camera's layers
    background   colour where no Gaussian covers a pixel
    table_z      the table plane's height in the base frame (to find the table's Gaussians for a texture)
    gather_ms    after a first frame request, wait at most this long for the other attached slots' frames
    """

    def __init__(self, parts: dict[str, Any], options: Any, slots: int, cameras: int, size: tuple[int, int],
                 background=(0.0, 0.0, 0.0), table_z: float = 0.0, gather_ms: float = 2.0,
                 start_timeout_s: float = 600.0) -> None:  # fmt: skip
        if slots < 1 or cameras < 1:
            raise ValueError(f"a splat server needs at least one slot and one camera, got {slots} and {cameras}")
        self.args = (parts, options, int(slots), int(cameras), tuple(int(v) for v in size),
                     tuple(float(c) for c in background), float(table_z), float(gather_ms) / 1000.0)  # fmt: skip
        self.start_timeout_s = start_timeout_s
        self.proc = None
        self.handle: SplatServerHandle | None = None
        self.stats: dict[str, Any] = {}

    def start(self) -> SplatServerHandle:
        ctx = mp.get_context("spawn")  # CUDA, numba and Genesis do not survive fork
        parts, options, slots, cameras, (w, h), *_ = self.args
        requests, free = ctx.Queue(), ctx.Queue()
        pipes = [ctx.Pipe(duplex=False) for _ in range(slots)]
        status_recv, status_send = ctx.Pipe(duplex=False)
        buffers = [ctx.RawArray("f", cameras * h * w * LAYERS) for _ in range(slots)]
        for s in range(slots):
            free.put(s)
        self.proc = ctx.Process(target=_serve, args=(*self.args, requests, [p[1] for p in pipes], buffers,
                                                     status_send, os.getpid()), daemon=True)  # fmt: skip
        self.proc.start()
        for _, send in pipes:  # the server holds them now: a dead server is an EOF at its clients
            send.close()
        status_send.close()
        self._status, self._requests = status_recv, requests
        try:
            if status_recv.poll(self.start_timeout_s):
                kind, payload = status_recv.recv()
            else:
                kind, payload = "error", f"it did not start within {self.start_timeout_s:.0f} s"
        except EOFError:
            self.proc.join(timeout=5)
            kind, payload = "error", (f"it died while starting (exit code {self.proc.exitcode}); a script that starts "
                                      "one must guard its main code with `if __name__ == '__main__':` (processes "
                                      "are spawned, and re-import the script)")  # fmt: skip
        if kind != "ready":
            self.close()
            raise SplatServerError(f"the splat server failed to start: {payload}")
        self.stats = {"gaussians": payload}
        self.handle = SplatServerHandle(requests, [p[0] for p in pipes], buffers, free, cameras, (w, h),
                                        self.proc.pid)  # fmt: skip
        return self.handle

    def close(self) -> dict[str, Any]:
        """Stop the server; -> its statistics (frames, batches, mean and largest batch, seconds rendering)."""
        if self.proc is None:
            return self.stats
        if self.proc.is_alive():
            try:
                self._requests.put(None)
                if self._status.poll(30):
                    kind, payload = self._status.recv()
                    if kind == "stats":
                        self.stats.update(payload)
            except (EOFError, OSError):
                pass
            self.proc.join(timeout=10)
            if self.proc.is_alive():
                self.proc.kill()
        self.proc = None
        return self.stats

    def __enter__(self) -> SplatServerHandle:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def _serve(parts, options, slots, cameras, size, background, table_z, gather_s, requests, replies, buffers, status,
           parent) -> None:  # fmt: skip  (the server process)

    die_with_parent(parent)
    try:
        import torch

        from .splat_world import SplatWorld, SplatWorldBatch

        world = SplatWorld.from_files(parts, options)
        batch = SplatWorldBatch(world, slots)
        w, h = size
        outs = [np.frombuffer(b, np.float32).reshape(cameras, h, w, LAYERS) for b in buffers]
        status.send(("ready", len(world)))
    except BaseException as e:  # a bad input file says what it is; anything else, where
        status.send(("error", str(e) if isinstance(e, M2MError) else traceback.format_exc()))
        return
    table = None  # the table's Gaussians (env.table_texture.TableGaussians), found at the first texture
    textured: set[int] = set()
    attached: set[int] = set()
    pending: dict[int, tuple] = {}
    stats = {"frames": 0, "batches": 0, "largest_batch": 0, "render_s": 0.0}

    def reply(slot: int, msg: tuple) -> None:
        try:
            replies[slot].send(msg)
        except (BrokenPipeError, OSError):  # that worker is gone; the others go on
            attached.discard(slot)

    def handle(item) -> None:
        nonlocal table
        kind, slot = item[0], item[1]
        if kind == "frame":
            pending[slot] = item[2:]
        elif kind == "attach":
            attached.add(slot)
            batch.forget(slot)
            reply(slot, ("ok", None))
        elif kind == "detach":
            attached.discard(slot)
            pending.pop(slot, None)
        elif kind == "episode":
            try:
                scale, texture = item[2], item[3]
                batch.set_scale(slot, scale)
                if texture is not None or slot in textured:
                    if table is None:
                        table = TableGaussians.find(world.gaussians, world.static_rows, table_z)
                    with torch.no_grad():
                        batch.stack["sh"][slot, table.rows, 0] = table.sh_dc(texture)
                    textured.discard(slot) if texture is None else textured.add(slot)
                reply(slot, ("ok", None))
            except Exception:
                reply(slot, ("error", traceback.format_exc()))

    def render_pending() -> None:
        copies = sorted(pending)
        try:
            t0 = time.perf_counter()
            poses: list = [None] * slots
            for b in copies:
                poses[b] = pending[b][0]
            batch.set_poses(poses)
            V = np.stack([pending[b][1] for b in copies])
            K = np.stack([pending[b][2] for b in copies])
            rgb, alpha, depth = batch.render(V, K, w, h, background, copies=copies)
            for i, b in enumerate(copies):
                outs[b][..., :3], outs[b][..., 3], outs[b][..., 4] = rgb[i], alpha[i], depth[i]
            stats["render_s"] += time.perf_counter() - t0
            stats["frames"] += len(copies)
            stats["batches"] += 1
            stats["largest_batch"] = max(stats["largest_batch"], len(copies))
            msgs = {b: ("ok", None) for b in copies}
        except Exception as e:  # out of GPU memory (its message says what to lower), a bad camera: every asker
            text = str(e) if isinstance(e, M2MError) else traceback.format_exc()
            msgs = {b: ("error", text) for b in copies}
        pending.clear()
        for b, m in msgs.items():
            reply(b, m)

    running = True
    while running:
        item = requests.get()
        if item is None:
            break
        handle(item)
        deadline = time.perf_counter() + gather_s
        while running:  # gather: the other attached slots' frames, for at most gather_s
            try:
                left = deadline - time.perf_counter()
                waiting = pending and len(pending) < len(attached) and left > 0
                item = requests.get(timeout=left) if waiting else requests.get_nowait()
            except queue.Empty:
                break
            if item is None:
                running = False
            else:
                handle(item)
        if pending:
            render_pending()
    stats["mean_batch"] = stats["frames"] / max(stats["batches"], 1)
    try:
        status.send(("stats", stats))
    except (BrokenPipeError, OSError):
        pass


class RemoteSplatLayer:
    """A worker's slot of a running :class:`SplatServer`: its episodes' splat layers, drawn by the server."""

    def __init__(self, handle: SplatServerHandle, timeout_s: float = 600.0, slot_wait_s: float = 60.0) -> None:
        self.handle, self.timeout_s = handle, timeout_s
        try:
            self.slot = handle.free.get(timeout=slot_wait_s)
        except queue.Empty:
            raise SplatServerError(f"every one of the splat server's {len(handle.replies)} slots is taken: start it "
                                   "with as many slots as workers") from None  # fmt: skip
        w, h = handle.size
        self._buffer = np.frombuffer(handle.buffers[self.slot], np.float32).reshape(handle.cameras, h, w, LAYERS)
        self._call(("attach", self.slot))

    def _call(self, msg: tuple) -> None:
        self.handle.requests.put(msg)
        conn = self.handle.replies[self.slot]
        try:
            if not conn.poll(self.timeout_s):
                raise SplatServerError(f"the splat server (pid {self.handle.pid}) did not answer within "
                                       f"{self.timeout_s:.0f} s")  # fmt: skip
            kind, payload = conn.recv()
        except (EOFError, OSError):
            raise SplatServerError(f"the splat server (pid {self.handle.pid}) died; see its error above "
                                   "(out of memory?)") from None  # fmt: skip
        if kind == "error":
            raise SplatServerError(f"the splat server failed: {payload}")

    def start_episode(self, object_scale: float = 1.0, table_texture: Any = None) -> None:
        """A new episode in this slot: its objects' scale factor and table look (None: as reconstructed)."""
        self._call(("episode", self.slot, float(object_scale), table_texture))

    def render(self, poses: dict[str, np.ndarray], viewmats: np.ndarray, Ks: np.ndarray):
        """The parts at ``poses`` ({name: T_base_obj [4,4]}) from the slot's cameras (viewmats [C,4,4]
        base-to-camera, Ks [C,3,3] at the frame size) -> (rgb [C,H,W,3] in [0,1], alpha [C,H,W], depth [C,H,W]),
        float32 copies."""
        viewmats, Ks = np.asarray(viewmats, np.float64), np.asarray(Ks, np.float64)
        C = self.handle.cameras
        if viewmats.shape != (C, 4, 4) or Ks.shape != (C, 3, 3):
            raise ValueError(f"this splat server draws {C} camera(s): viewmats [{C},4,4] and Ks [{C},3,3], got "
                             f"{viewmats.shape} and {Ks.shape}")  # fmt: skip
        poses = {k: np.asarray(v, np.float64) for k, v in poses.items()}
        self._call(("frame", self.slot, poses, viewmats, Ks))
        out = self._buffer.copy()
        return out[..., :3], out[..., 3], out[..., 4]

    def close(self) -> None:
        """Give the slot back."""
        if self.slot is None:
            return
        try:
            self.handle.requests.put(("detach", self.slot))
            self.handle.free.put(self.slot)
        except (OSError, ValueError):
            pass
        self.slot = None
