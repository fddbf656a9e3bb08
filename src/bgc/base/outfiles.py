"""The one checked writer for every file a bgc command writes.

Every output (``compile -o``, ``graph -o``, ``simulate --out`` and ``--plot``, ``accuracy
--out``) goes through :func:`write_output`, which

* refuses to replace an input of the same run (the model, the files it imports, the scene),
  compared by device and inode (``os.stat``), so a symbolic or hard link to an input, or
  another spelling of its path, is caught too;
* refuses to replace anything that is not a regular file: a device (``/dev/null``), a FIFO,
  a socket, a folder, and a symbolic link (bgc never writes through a link, even to a regular
  file: name the target itself);
* writes a temporary file beside the target and renames it over the target, so a failure at
  any point leaves the target as it was and no temporary behind;
* gives the file the permissions the umask allows (0o666 & ~umask), as ``open`` would;
* turns every ``OSError`` (an empty name, a name too long, a read-only or missing place, a
  parent that is a file) into one :class:`OutputError` line naming the path: exit status 2.

Folders the outputs need are created (as ``mkdir -p``), and a failure there is the same one
line.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from bgc.base.errors import ModelError
from bgc.base.limits import LIMITS
from bgc.base.safeio import read_text_bounded

__all__ = ["OutputError", "Inputs", "write_output", "check_output", "prepare_folder",
           "check_folder",
           "model_inputs", "umask"]


class OutputError(ModelError):
    """An output that cannot or must not be written (exit status 2)."""

    def __init__(self, what: str, path, reason: str):
        super().__init__(None, f"{what} {_show(path)}: {reason}")


def _show(path) -> str:
    """A path for a one-line message: quoted, control characters escaped, long names cut."""
    s = repr(os.fspath(path)) if not isinstance(path, str) else repr(path)
    return s if len(s) <= 200 else s[:120] + "..." + s[-60:]


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link"))


def _kind(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


class Inputs:
    """The files a run reads, by (device, inode): no output may replace one of them."""

    def __init__(self, paths=()):
        self.ids: dict[tuple[int, int], str] = {}
        for p in paths:
            self.add(p)

    def add(self, path) -> None:
        try:
            st = os.stat(path)
        except (OSError, ValueError):
            return  # unreadable: the run fails on it anyway, nothing to protect
        self.ids.setdefault((st.st_dev, st.st_ino), os.fspath(path))

    def owner(self, st) -> str | None:
        return self.ids.get((st.st_dev, st.st_ino))




def model_inputs(model_path) -> list[Path]:
    """The model file and every file it imports, transitively (read after the model has
    parsed, so the files are known to be valid and bounded; each file visited once)."""
    out: list[Path] = []
    seen: set[str] = set()
    todo = [Path(model_path)]
    while todo and len(out) <= LIMITS.import_files:
        p = todo.pop()
        try:
            key = str(p.resolve())
        except (OSError, RuntimeError, ValueError):
            continue
        if key in seen:
            continue
        seen.add(key)
        out.append(p)
        try:  # read as the parser reads (regular files within the size limit only)
            text = read_text_bounded(p, None, "model file", LIMITS.model_bytes)
            # a file that never says "imports" imports nothing: no need to load it
            doc = None
            if "imports" in text:
                import yaml

                doc = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        except Exception:  # noqa: BLE001 - best effort: parse_file has already checked it
            continue
        imports = doc.get("imports") if isinstance(doc, dict) else None
        for item in imports if isinstance(imports, list) else ():
            if isinstance(item, dict) and isinstance(item.get("file"), str):
                todo.append(p.parent / item["file"])
    return out


def umask() -> int:
    """The process's umask: from /proc/self/status where Linux shows it, else by setting and
    restoring it (os.umask can only be read that way)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def check_output(path, inputs: Inputs | None = None, what: str = "output") -> Path:
    """The checks of :func:`write_output` without writing: an error if ``path`` must not be
    replaced (see the module's docstring); the path otherwise."""
    if path is None or os.fspath(path) == "":
        raise OutputError(what, "", "the path is empty")
    text = os.fspath(path)
    if "\0" in text:
        raise OutputError(what, text, "the path contains a NUL character")
    p = Path(text)
    if text.endswith(("/", os.sep)) or p.name in ("", ".", ".."):
        raise OutputError(what, text, "names a folder, not a file")
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise OutputError(what, text, "a part of the path is a file, not a folder") from None
    except OSError as exc:
        raise OutputError(what, text, _reason(exc)) from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise OutputError(what, text, "is a symbolic link; bgc does not write through "
                                          "links: name the file itself")
        if not stat.S_ISREG(st.st_mode):
            raise OutputError(what, text, f"is {_kind(st.st_mode)}, not a regular file; bgc "
                                          "replaces only regular files")
        owner = inputs.owner(st) if inputs is not None else None
        if owner is not None:
            same = "" if os.path.abspath(owner) == os.path.abspath(text) else \
                f" (the same file as {_show(owner)})"
            raise OutputError(what, text, f"is an input of this run{same}; choose another "
                                          "output name")
    return p


def _folder_path(folder, what: str) -> tuple[str, Path]:
    """(the path's text, the Path) of a folder argument: an error if empty or holding NUL."""
    text = os.fspath(folder)
    if text == "":
        raise OutputError(what, "", "the path is empty")
    if "\0" in text:
        raise OutputError(what, text, "the path contains a NUL character")
    return text, Path(text)


def prepare_folder(folder, what: str = "output folder") -> Path:
    """Create ``folder`` (and its parents) if missing; an error if it cannot be."""
    text, p = _folder_path(folder, what)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(what, text, "exists and is not a folder") from None
    except NotADirectoryError:
        raise OutputError(what, text, "a part of the path is a file, not a folder") from None
    except OSError as exc:
        raise OutputError(what, text, f"cannot create the folder: {_reason(exc)}") from None
    if not p.is_dir():
        raise OutputError(what, text, "exists and is not a folder")
    return p


def check_folder(folder, what: str = "output folder") -> Path:
    """The checks of :func:`prepare_folder` without creating anything: ``folder`` is a folder,
    or the nearest part of it that exists is a folder bgc may create entries in."""
    text, p = _folder_path(folder, what)
    probe = p
    while True:
        try:
            st = os.stat(probe)
        except FileNotFoundError:
            if probe.parent == probe:
                break
            probe = probe.parent
            continue
        except NotADirectoryError:
            raise OutputError(what, text, "a part of the path is a file, not a folder") from None
        except OSError as exc:
            raise OutputError(what, text, _reason(exc)) from None
        if not stat.S_ISDIR(st.st_mode):
            raise OutputError(what, text, "exists and is not a folder" if probe == p else
                              "a part of the path is a file, not a folder")
        if not os.access(probe, os.W_OK | os.X_OK):
            raise OutputError(what, text, f"cannot write in {_show(str(probe))}: Permission "
                                          "denied")
        break
    return p


def write_output(path, data, inputs: Inputs | None = None, what: str = "output") -> Path:
    """Write ``data`` (str: UTF-8 with ``\\n`` line ends; or bytes) to ``path``, checked and
    atomic (see the module's docstring). Returns the path."""
    p = check_output(path, inputs, what)
    if isinstance(data, str):
        data = data.encode("utf-8")
    parent = p.parent
    if str(parent) not in ("", "."):
        prepare_folder(parent, what + " folder")
    import tempfile

    tmp = None
    try:
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name[:100]}.", suffix=".tmp",
                                       dir=str(parent) or ".")
        except OSError as exc:
            raise OutputError(what, os.fspath(path), "cannot create a file in "
                              f"{_show(str(parent))}: {_reason(exc)}") from None
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                os.fchmod(fh.fileno(), 0o666 & ~umask())
            check_output(path, inputs, what)  # still a regular file (or none) that is no input
            os.replace(tmp, p)
        except OSError as exc:
            raise OutputError(what, os.fspath(path), _reason(exc)) from None
        tmp = None
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
    return p
