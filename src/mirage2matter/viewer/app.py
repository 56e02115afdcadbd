"""The viewer: the scene (``scene``), its GUI (layers, joint sliders, episodes), object drags written back through a
callback, episode playback, and the export to one HTML file.

Viser runs a client's GUI and gizmo callbacks in its thread pool; a drag's write holds ``_write_lock`` so two drags
never write at once, and the callback (the command's: ``m2m world move``'s path) holds the workspace lock.
"""

from __future__ import annotations

import contextlib
import io
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write
from ..errors import M2MError
from ..geometry.rotation import quat_to_matrix
from ..geometry.sim3 import Sim3
from .config import ViewerConfig
from .episodes import Episode, dataset_episode, eval_episode
from .inputs import ViewerError, ViewerInputs
from .kinematics import LinkPoser
from .scene import add_board, add_cameras, add_keyframes, add_objects, add_robot, add_scene, placement_pose, wxyz

__all__ = ["MoveObject", "TwinViewer"]

# (object name, new origin xyz [3] in the base frame, turn about z in degrees relative to its placement) -> the
# placement written; raises an M2MError when the edit is refused (another writer, an invalid world)
MoveObject = Callable[[str, np.ndarray, float], Sim3]


class TwinViewer:
    """A viser server showing ``inputs``. ``on_move``: where a released drag goes (None: objects stay put). ``log``:
    progress and messages for the terminal. ``port=0`` in ``cfg`` serves on any free port (an export)."""

    def __init__(self, inputs: ViewerInputs, cfg: ViewerConfig, on_move: MoveObject | None = None,
                 log: Callable[[str], None] = print) -> None:  # fmt: skip
        import viser

        self.inputs, self.cfg, self.on_move, self.log = inputs, cfg, on_move, log
        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner names 0.0.0.0; the command prints the URL
            self.server = viser.ViserServer(host=cfg.host, port=cfg.port, verbose=False)
        self.poser = LinkPoser(inputs.robot)
        self.q = self.poser.full_q(cfg.joints)  # [n_dofs] shown when no episode plays
        self.placements = {it.name: it.placement for it in self._items()}
        self.episode: Episode | None = None
        self.frame = 0
        self.playing = False
        self.messages: list[str] = []  # what the page said about edits, newest last
        self._write_lock = threading.Lock()
        t0 = time.perf_counter()
        try:
            self._build()
        except BaseException:
            self.server.stop()
            raise
        self.load_s = time.perf_counter() - t0

    @property
    def url(self) -> str:
        return f"http://{self.cfg.host}:{self.server.get_port()}"

    def _items(self) -> list[Any]:
        w = self.inputs.world
        return [] if w is None else [*w.objects, *w.articulated]

    # ---- building ----------------------------------------------------------------------------------------------
    def _build(self) -> None:
        gui = self.server.gui
        self.status = gui.add_markdown("**Loading the twin ...**")
        bar = gui.add_progress_bar(0.0, animated=True)
        steps = 4 + len(self._items())
        done = [0]

        def progress(what: str) -> None:
            done[0] += 1
            bar.value = min(100.0, 100.0 * done[0] / steps)
            self.status.content = f"**Loading** {what} ..."
            self.log(f"view: loading {what}")

        s = self.server
        s.scene.set_up_direction("+z")
        # the first view: above and behind the first keyframe (in its place, its own frustum's picture fills the
        # view), looking down at the middle: the table, the robot and the capture's orbit in one picture
        centre = np.mean([np.zeros(3)] + [it.placement.translation for it in self._items()], axis=0)
        centre[2] = 0.1
        eye = (np.asarray(self.inputs.keyframes[0].T_world_cam)[:3, 3] if self.inputs.keyframes
               else centre + [0.75, -0.55, 0.5])  # fmt: skip
        s.initial_camera.look_at = tuple(centre)
        s.initial_camera.position = tuple(centre + 1.3 * (eye - centre) + [0.0, 0.0, 0.7])
        self.layers: dict[str, list[Any]] = {}
        scene = add_scene(s, self.inputs, self.cfg, progress)
        self.layers["scene"] = [scene] if scene is not None else []
        self.objects, self.layers["collision"] = add_objects(s, self.inputs, self.cfg, self.on_move is not None,
                                                             progress)  # fmt: skip
        self.layers["objects"] = list(self.objects.values())
        self.links, self.layers["robot"] = add_robot(s, self.inputs, self.poser.poses(self.q), self.cfg, progress)
        self.cameras = add_cameras(s, self.inputs, self.links)
        self.layers["cameras"] = list(self.cameras.values())
        self.layers["keyframes"] = add_keyframes(s, self.inputs, self.cfg, progress)
        board = add_board(s, self.inputs.board)
        self.layers["board"] = [board] if board is not None else []
        for name, node in self.objects.items():
            if hasattr(node, "on_update"):
                node.on_update(lambda event, name=name: self._dragged(name, event))
        bar.remove()
        self._gui()

    def _gui(self) -> None:
        gui = self.server.gui
        missing = "".join(f"\n- {m}" for m in self.inputs.missing)
        self.status.content = ("**The twin**" + (f" (not there yet:{missing})" if missing else "")
                               + ("\n\nDrag an object's gizmo to move it: world.yaml is saved on release."
                                  if self.objects and self.on_move else ""))  # fmt: skip
        self.edits = gui.add_markdown("")
        with gui.add_folder("Layers"):
            for name, handles in self.layers.items():
                if handles:
                    box = gui.add_checkbox(name, initial_value=name != "collision")
                    box.on_update(lambda _, name=name, box=box: self.show(name, box.value))
        spec = self.inputs.robot
        self.sliders = []
        with gui.add_folder("Robot joints", expand_by_default=False):
            for i, joint in enumerate(spec.arm_joints):
                lo, hi = spec.joint_limits[i]
                sl = gui.add_slider(joint, min=float(lo), max=float(hi), step=0.01, initial_value=float(self.q[i]))
                sl.on_update(lambda _, i=i, sl=sl: self._joint(i, sl.value))
                self.sliders.append(sl)
        sources = [f"dataset {n}" for n in self.inputs.datasets] + [f"eval {n}" for n in self.inputs.evals]
        if not sources:
            return
        with gui.add_folder("Episode"):
            self.source = gui.add_dropdown("source", sources)
            self.episode_index = gui.add_number("episode", initial_value=0, min=0, step=1)
            gui.add_button("Load").on_click(lambda _: self._load_from_gui())
            self.slider = gui.add_slider("frame", min=0, max=1, step=1, initial_value=0, disabled=True)
            self.slider.on_update(lambda _: self.set_frame(int(self.slider.value)))
            gui.add_button("Play").on_click(lambda _: self.play())
            self.outcome = gui.add_markdown("")
            self.pictures: dict[str, Any] = {}

    # ---- layers and the robot ----------------------------------------------------------------------------------
    def show(self, layer: str, visible: bool) -> None:
        for h in self.layers.get(layer, []):
            h.visible = visible

    def _joint(self, i: int, value: float) -> None:
        if self.episode is None or self.episode.state is None:
            self.q[i] = value
            self.pose_robot(self.q)

    def pose_robot(self, q: np.ndarray) -> None:
        poses = self.poser.poses(q)
        with self.server.atomic():
            for link, node in self.links.items():
                T = poses[link]
                node.wxyz, node.position = wxyz(T[:3, :3]), T[:3, 3]

    # ---- editing -------------------------------------------------------------------------------------------------
    def _dragged(self, name: str, event: Any) -> None:
        if event.phase != "end":
            return
        node = self.objects[name]
        base = self.placements[name]
        R_new = np.asarray(quat_to_matrix(np.asarray(node.wxyz, np.float64)), np.float64)
        R_rel = R_new @ np.asarray(base.rotation).T
        yaw = math.degrees(math.atan2(R_rel[1, 0], R_rel[0, 0]))
        xyz = np.asarray(node.position, np.float64)
        self.move(name, xyz, yaw)

    def move(self, name: str, xyz: np.ndarray, yaw_deg: float) -> bool:
        """Write ``name`` at ``xyz`` turned ``yaw_deg`` about z through ``on_move``; the gizmo goes where the world
        now has it (back where it was when refused). Whether it was saved."""
        ok = False
        if self.episode is not None:
            msg = f"{name}: not saved: an episode is shown (its start poses are not the world's); reload the page"
        else:
            try:
                with self._write_lock:
                    self.placements[name] = self.on_move(name, xyz, yaw_deg)
                t = self.placements[name].translation
                msg, ok = f"{name}: moved to {t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f} m; world.yaml saved", True
            except M2MError as e:
                msg = f"{name}: not saved: {e}"
        q, p = placement_pose(self.placements[name])
        self.objects[name].wxyz, self.objects[name].position = q, p
        self.messages.append(msg)
        self.edits.content = f"**{'Saved' if ok else 'Refused'}:** {msg}"
        self.log(f"view: {msg}")
        return ok

    # ---- episodes ------------------------------------------------------------------------------------------------
    def _load_from_gui(self) -> None:
        kind, name = self.source.value.split(" ", 1)
        try:
            self.load_episode(kind, name, int(self.episode_index.value))
        except M2MError as e:
            self.outcome.content = f"**Cannot load:** {e}"

    def load_episode(self, kind: str, name: str, index: int) -> Episode:
        """Show episode ``index`` of dataset (``kind`` "dataset") or evaluation ("eval") ``name``."""
        table = self.inputs.datasets if kind == "dataset" else self.inputs.evals
        if name not in table:
            raise ViewerError(f"no {kind} named {name!r} in the workspace; there are: {', '.join(table) or 'none'}")
        ep = (dataset_episode(table[name], index, self.inputs.robot) if kind == "dataset"
              else eval_episode(table[name], index))  # fmt: skip
        if ep.length == 0:
            raise ViewerError(f"{ep.title}: no frames recorded")
        self.playing = False
        self.episode = ep
        for obj, T in ep.start_poses.items():
            if obj in self.objects:
                self.objects[obj].wxyz, self.objects[obj].position = wxyz(T[:3, :3]), T[:3, 3]
        if hasattr(self, "slider"):
            self.slider.max = ep.length - 1
            self.slider.disabled = False
            for h in self.pictures.values():
                h.remove()
            self.pictures = {c: self.server.gui.add_image(f[0], label=c, format="jpeg") for c, f in ep.frames.items()}
        verdict = {True: "success", False: "failure", None: "outcome unknown"}[ep.success]
        self._outcome = f"**{ep.title}**: {verdict} ({ep.note})"
        self.set_frame(0)
        return ep

    def set_frame(self, t: int) -> None:
        ep = self.episode
        if ep is None:
            return
        t = int(np.clip(t, 0, ep.length - 1))
        self.frame = t
        if ep.state is not None:
            self.pose_robot(ep.state[t])
        for cam, frames in ep.frames.items():
            if cam in self.pictures:
                self.pictures[cam].image = frames[min(t, len(frames) - 1)]
            if cam in self.cameras:  # the recorded picture on the camera's frustum too (what an export shows)
                self.cameras[cam].image = frames[min(t, len(frames) - 1)]
        if hasattr(self, "slider") and int(self.slider.value) != t:
            self.slider.value = t
        if hasattr(self, "outcome"):
            self.outcome.content = f"{self._outcome}\n\nframe {t} / {ep.length - 1}"

    def play(self, wait: bool = False) -> None:
        """Play the shown episode from its current frame to its last (in the background unless ``wait``)."""
        ep = self.episode
        if ep is None or self.playing:
            return
        self.playing = True
        start = 0 if self.frame >= ep.length - 1 else self.frame

        def run() -> None:
            for t in range(start, ep.length):
                if not self.playing or self.episode is not ep:
                    return
                self.set_frame(t)
                time.sleep(1.0 / ep.fps)
            self.playing = False

        threading.Thread(target=run, daemon=True).start() if not wait else run()

    # ---- export --------------------------------------------------------------------------------------------------
    def export_html(self, path: Path) -> int:
        """The scene as one HTML file that opens without a server (viser's serializer with its client inlined; an
        episode plays as its animation); bytes written."""
        serializer = self.server.get_scene_serializer()
        ep = self.episode
        if ep is not None:
            for t in range(ep.length):
                self.set_frame(t)
                serializer.insert_sleep(1.0 / ep.fps)
        html = serializer.as_html()
        with atomic_write(Path(path), "w", encoding="utf-8") as f:
            f.write(html)
        return len(html.encode("utf-8"))

    def close(self) -> None:
        self.playing = False
        self.server.stop()
