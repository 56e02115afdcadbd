"""Files as content, for workers on machines that do not see the driver's disk.

A worker on another node cannot open the world's files where the driver reads them (a cluster has no shared disk).
:func:`pack` reads the files an episode source needs once, on the driver, into a :class:`Shipment` (bytes, put
into Ray's object store once per run); a worker unpacks it into a folder of its own machine (:func:`unpack`, once
per node and content) and :func:`relocate` renames every path of the source's configuration from the driver's
folder to that one. :class:`ShippedFactory` does both the first time a worker builds its source.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import M2MError
from ..robots import is_spec_file

__all__ = ["ShipError", "Shipment", "ShippedFactory", "pack", "pack_under", "relocate", "unpack", "world_files"]


class ShipError(M2MError, RuntimeError):
    """A file an episode source needs cannot be read on the driver (so no worker could have it)."""


@dataclass(frozen=True)
class Shipment:
    """Files read on the driver. origin: the folder they were read from there; files: (path relative to origin,
    content) pairs; digest: the content's hash (names the folder a worker unpacks it into)."""

    origin: str
    files: tuple[tuple[str, bytes], ...]
    digest: str

    @property
    def nbytes(self) -> int:
        return sum(len(b) for _, b in self.files)


def _walk(path: Path) -> Iterable[Path]:
    if path.is_dir():
        yield from (p for p in sorted(path.rglob("*")) if p.is_file())
    elif path.is_file():
        yield path
    else:
        raise ShipError(f"{path} is named by the world but does not exist; compose the world again")


def pack(paths: Iterable[Path], origin: Path) -> Shipment:
    """The files (and folders' files) ``paths`` that lie under ``origin``, as content; paths elsewhere are left out
    (they are the environment's: installed packages, bundled robot models, which every node has)."""
    origin = Path(origin).resolve()
    found: dict[str, bytes] = {}
    for p in paths:
        p = Path(p).resolve()
        if origin not in p.parents:
            continue
        for f in _walk(p):
            rel = f.relative_to(origin).as_posix()
            if rel not in found:
                try:
                    found[rel] = f.read_bytes()
                except OSError as e:
                    raise ShipError(f"cannot read {f} to send it to the workers: {e}") from None
    files = tuple(sorted(found.items()))
    h = hashlib.sha1()
    for rel, data in files:
        h.update(rel.encode() + b"\0" + hashlib.sha1(data).digest())
    return Shipment(str(origin), files, h.hexdigest())


def pack_under(paths: Iterable[Path], origins: Iterable[Path]) -> tuple[Shipment, ...]:
    """The files ``paths`` as one shipment per folder of ``origins`` holding some of them (each path goes to the first
    origin it lies under; outside all of them: left out, as :func:`pack` leaves them)."""
    origins = [Path(o).resolve() for o in origins]
    groups: dict[Path, list[Path]] = {}
    for p in paths:
        p = Path(p).resolve()
        home = next((o for o in origins if o == p or o in p.parents), None)
        if home is not None:
            groups.setdefault(home if home != p else p.parent, []).append(p)
    return tuple(pack(ps, o) for o, ps in groups.items())


def world_files(world: Any) -> list[Path]:
    """Every file or folder an environment built on the world (``world.config.WorldConfig``) opens (a mesh with the
    materials and textures beside it, as ``m2m world insert`` copies them)."""
    out: list[Path] = [world.root]
    parts = [o.part for o in world.objects] + [p for a in world.articulated for p in (a.base, a.cap)]
    for part in parts:
        out += [p for p in (part.gaussians, part.collision) if p is not None]
        if part.mesh is not None:
            out.append(part.mesh)
            out += [x for x in part.mesh.parent.glob("*") if x.suffix.lower() in (".mtl", ".png", ".jpg", ".jpeg")]
    robot = world.robot
    out += [p for p in (world.scene_gaussians, robot.gaussians) if p is not None]
    out += [Path(f) for f in (robot.name if is_spec_file(robot.name) else "", robot.file) if f and Path(f).exists()]
    return out


def unpack(shipment: Shipment, cache: Path | None = None) -> Path:
    """The folder on this machine holding ``shipment``'s files, written once per content: several workers of a node
    share it, each writing its own temporary copy and renaming it into place (the first rename wins)."""
    cache = Path(cache) if cache is not None else Path(tempfile.gettempdir()) / "m2m-shipped"
    dest = cache / shipment.digest
    if (dest / ".complete").is_file():
        return dest
    cache.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{shipment.digest}-", dir=cache))
    for rel, data in shipment.files:
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp / rel).write_bytes(data)
    (tmp / ".complete").write_bytes(b"")
    try:
        os.rename(tmp, dest)
    except OSError:  # another worker of this node renamed its copy first: the same content

        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def _moved(value: Any, src: Path, dst: Path) -> Any:
    if isinstance(value, Path | str) and os.path.isabs(value):
        p = Path(value)
        if p == src or src in p.parents:
            new = dst / p.relative_to(src)
            return new if isinstance(value, Path) else str(new)
        return value
    if isinstance(value, tuple | list):
        return type(value)(_moved(v, src, dst) for v in value)
    if isinstance(value, dict):
        return {k: _moved(v, src, dst) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            object.__setattr__(value, f.name, _moved(getattr(value, f.name), src, dst))  # frozen ones too
    return value


def relocate(obj: Any, src: Path, dst: Path) -> Any:
    """A deep copy of the dataclass ``obj`` whose absolute paths (``Path`` or ``str``) under ``src`` name the same
    files under ``dst``."""
    return _moved(copy.deepcopy(obj), Path(src), Path(dst))


@dataclass(frozen=True, eq=False)
class ShippedFactory:
    """A source factory with the files it reads, for a worker on any machine: ``local()`` is the factory with its
    files unpacked on this machine and its paths renamed there (a worker asks once per run); calling it builds the
    source from that. ``others``: files from other folders (a policy or a sample outside the workspace)."""

    factory: Any
    shipment: Shipment
    others: tuple[Shipment, ...] = ()

    def local(self) -> Any:
        out = self.factory
        for s in (self.shipment, *self.others):
            out = relocate(out, Path(s.origin), unpack(s))
        return out

    def __call__(self) -> Any:
        return self.local()()
