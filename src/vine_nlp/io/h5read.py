"""Opening an HDF5 archive to read it: the one way every reader of vine_nlp does.

:func:`open_archive` opens the file through :func:`vine_nlp.io.files.open_input` (a regular
file within MAX_FILE_BYTES; never a pipe or a device) and, before any value is read, walks every
link and attribute of it once and refuses:

* soft and external links (an archive is one file: nothing is read through a link to another
  file or object, so a link to a pipe cannot block and another file's data cannot be copied in),
* virtual datasets and datasets kept in external raw files,
* a dataset or attribute whose declared size is over MAX_DATASET_ELEMENTS values, all datasets
  together over MAX_ARCHIVE_VALUES, more than MAX_ARCHIVE_OBJECTS links and attributes, and more
  than MAX_CHUNKS chunks in one dataset: compressed data cannot expand beyond the limits,
* names that are not printable text of at most MAX_NAME_CHARS characters, and datasets of
  anything but real numbers.

Each refusal is one :class:`ArchiveError` ``(file, path in the archive, reason)``.
"""

from __future__ import annotations

import contextlib
import math

import h5py

from vine_nlp.errors import InputError
from vine_nlp.io import files, limits

MAX_CHUNKS = 100_000  # chunks of one dataset (each is one lookup when read)


class ArchiveError(InputError, ValueError):
    """An archive that cannot be used: ``(file, dataset path, reason)``; the command line
    prints one line and exits 2. A ValueError too, for callers written before it existed."""


@contextlib.contextmanager
def open_archive(path):
    """The open, checked archive (module docstring) as an h5py.File; ArchiveError and nothing else."""
    path = str(path)
    try:
        fh = files.open_input(path)
    except InputError as e:
        raise ArchiveError(path, e.key, e.reason) from None
    with fh:
        head = fh.read(8)
        fh.seek(0)
        if head != b"\x89HDF\r\n\x1a\n":  # an archive has no user block: the signature comes first
            raise ArchiveError(path, "file", "not an HDF5 file")
        h5 = None
        try:
            h5 = h5py.File(fh, "r")
            inspect(h5, path)
        except BaseException as exc:
            if h5 is not None:
                h5.close()
            if isinstance(exc, ArchiveError) or not isinstance(exc, (OSError, ValueError, RuntimeError, KeyError, TypeError)):
                raise
            raise ArchiveError(path, "file", f"cannot read the archive ({' '.join(str(exc).split())[:200]})") from None
        with h5:
            yield h5


def inspect(h5: h5py.File, path: str) -> None:
    """Refuse what the module docstring lists, reading no dataset."""
    found = []  # (key, reason) of the first refusal: h5py's visit cannot carry an exception out
    state = {"objects": 0, "values": 0}

    def visit(name, link):
        key = "/" + name
        reason = _name(name.rsplit("/", 1)[-1])
        if reason is None and not isinstance(link, h5py.HardLink):
            reason = f"a {type(link).__name__} (an archive is one file: links are not followed)"
        if reason is None:
            reason = _object(h5[name], state)
        if reason is None and state["objects"] > limits.MAX_ARCHIVE_OBJECTS:
            reason = f"more than {limits.MAX_ARCHIVE_OBJECTS} objects and attributes (vine_nlp.io.limits.MAX_ARCHIVE_OBJECTS)"
        if reason is not None:
            found.append((key, reason))
            return True  # stops the visit
        return None

    reason = _attributes(h5, state)
    if reason is not None:
        raise ArchiveError(path, f"/@{reason[0]}", reason[1])
    h5.visititems_links(visit)
    if found:
        raise ArchiveError(path, *found[0])


def _name(name: str) -> str | None:
    if not name.isprintable() or len(name) > limits.MAX_NAME_CHARS:
        return f"a name must be printable text of at most {limits.MAX_NAME_CHARS} characters"
    return None


def _object(obj, state) -> str | None:
    if isinstance(obj, h5py.Dataset):
        reason = _dataset(obj, state)
        if reason is not None:
            return reason
    elif not isinstance(obj, h5py.Group):
        return f"unsupported object ({type(obj).__name__})"
    reason = _attributes(obj, state)
    return None if reason is None else f"attribute {reason[0]!r}: {reason[1]}"


def _dataset(ds: h5py.Dataset, state) -> str | None:
    if ds.is_virtual:
        return "a virtual dataset (data from other files) is not read"
    if ds.id.get_create_plist().get_external_count():
        return "data stored in external files is not read"
    if ds.dtype.kind not in "fiub" or ds.dtype.fields or ds.dtype.subdtype:
        return f"must hold real numbers, got dtype {ds.dtype}"
    size = math.prod(ds.shape or ())
    if size > limits.MAX_DATASET_ELEMENTS:
        return f"{size} values, more than the limit of {limits.MAX_DATASET_ELEMENTS} (vine_nlp.io.limits.MAX_DATASET_ELEMENTS)"
    if ds.chunks and math.prod(-(-n // c) for n, c in zip(ds.shape, ds.chunks)) > MAX_CHUNKS:
        return f"stored in more than {MAX_CHUNKS} chunks (vine_nlp.io.h5read.MAX_CHUNKS)"
    state["values"] += size
    if state["values"] > limits.MAX_ARCHIVE_VALUES:
        return f"more than {limits.MAX_ARCHIVE_VALUES} values in all datasets (vine_nlp.io.limits.MAX_ARCHIVE_VALUES)"
    return None


def _attributes(obj, state) -> tuple[str, str] | None:
    """(name, reason) of the first attribute of ``obj`` refused, or None."""
    for name in obj.attrs:
        state["objects"] += 1
        reason = _name(name)
        if reason is None:
            aid = obj.attrs.get_id(name)
            size = math.prod(aid.shape or ()) * max(1, aid.dtype.itemsize // 8)
            if size > limits.MAX_DATASET_ELEMENTS:
                reason = f"{size} values, more than the limit of {limits.MAX_DATASET_ELEMENTS} (vine_nlp.io.limits.MAX_DATASET_ELEMENTS)"
        if reason is not None:
            return name, reason
    state["objects"] += 1
    return None
