"""Opening an HDF5 archive to read it: the one way every reader of vine_nlp does.

:func:`open_archive` opens the file through :func:`vine_nlp.io.files.open_input` (a regular file within MAX_FILE_BYTES)
and, before any value is read, walks every link and attribute once and refuses, as one :class:`ArchiveError` ``(file,
path in the archive, reason)``: soft and external links (nothing is read through a link: a link to a pipe cannot block,
another file's data cannot be copied in), virtual datasets and external raw storage, datasets of anything but numbers,
unprintable or overlong names, and declared sizes over the limits (one dataset or attribute, all datasets, objects,
chunks): compressed data cannot expand beyond them."""

from __future__ import annotations

import contextlib
import math

import h5py
import numpy as np

from vine_nlp import interrupt
from vine_nlp.errors import InputError
from vine_nlp.io import files, limits

MAX_CHUNKS = 100_000  # chunks of one dataset (each is one lookup when read)
_BAD_NAME = f"a name must be printable text of at most {limits.MAX_NAME_CHARS} characters"


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
            interrupt.hold("archive")  # tests: a signal while an archive is open in h5py
            yield h5


def inspect(h5: h5py.File, path: str) -> None:
    """Refuse what the module docstring lists, reading no dataset."""
    count = {"objects": 0, "values": 0}
    found = [("/", _attributes(h5, count))]  # the first refusal: h5py's visit cannot carry an exception out

    def visit(name, link):
        if name.count("/") >= limits.MAX_ARCHIVE_DEPTH:
            reason = f"nested more than {limits.MAX_ARCHIVE_DEPTH} groups deep (vine_nlp.io.limits.MAX_ARCHIVE_DEPTH)"
        elif not _good_name(name.rsplit("/", 1)[-1]):
            reason = _BAD_NAME
        elif not isinstance(link, h5py.HardLink):
            reason = f"a {type(link).__name__} (an archive is one file: links are not followed)"
        elif not isinstance(obj := h5[name], (h5py.Dataset, h5py.Group)):
            reason = f"unsupported object ({type(obj).__name__})"
        else:
            reason = (_dataset(obj, count) if isinstance(obj, h5py.Dataset) else None) or _attributes(obj, count)
            if reason is None and count["objects"] > limits.MAX_ARCHIVE_OBJECTS:
                reason = f"more than {limits.MAX_ARCHIVE_OBJECTS} objects and attributes (vine_nlp.io.limits.MAX_ARCHIVE_OBJECTS)"
        found.append((f"/{name}", reason))
        return True if reason else None  # True stops the visit

    if found[0][1] is None:
        h5.visititems_links(visit)
    refused = [f for f in found if f[1]]
    if refused:
        raise ArchiveError(path, *refused[0])


def _good_name(name: str) -> bool:
    return name.isprintable() and len(name) <= limits.MAX_NAME_CHARS


def _size(n: int) -> str | None:
    if n > limits.MAX_DATASET_ELEMENTS:
        return f"{n} values, more than the limit of {limits.MAX_DATASET_ELEMENTS} (vine_nlp.io.limits.MAX_DATASET_ELEMENTS)"
    return None


def _dataset(ds: h5py.Dataset, count) -> str | None:
    if ds.is_virtual:
        return "a virtual dataset (data from other files) is not read"
    if ds.id.get_create_plist().get_external_count():
        return "data stored in external files is not read"
    if ds.dtype.kind not in "fiub" or ds.dtype.fields or ds.dtype.subdtype:
        return f"must hold real numbers, got dtype {ds.dtype}"
    size = math.prod(ds.shape or ())
    count["values"] += size
    if ds.chunks and size <= limits.MAX_DATASET_ELEMENTS and math.prod(-(-n // c) for n, c in zip(ds.shape, ds.chunks)) > MAX_CHUNKS:
        return f"stored in more than {MAX_CHUNKS} chunks (vine_nlp.io.h5read.MAX_CHUNKS)"
    if count["values"] > limits.MAX_ARCHIVE_VALUES and size <= limits.MAX_DATASET_ELEMENTS:
        return f"more than {limits.MAX_ARCHIVE_VALUES} values in all datasets (vine_nlp.io.limits.MAX_ARCHIVE_VALUES)"
    return _size(size)


def _attributes(obj, count) -> str | None:
    """Why an attribute of ``obj`` is refused, or None."""
    count["objects"] += 1 + len(obj.attrs)
    for name in obj.attrs:
        aid = obj.attrs.get_id(name)
        reason = _size(math.prod(aid.shape or ()) * max(1, aid.dtype.itemsize // 8)) if _good_name(name) else _BAD_NAME
        if reason:
            return f"attribute {name[:80]!r}: {reason}"
    return None


def decode_attr(v):
    """An HDF5 attribute's value as Python gives it: bytes decoded, numpy scalars as numbers."""
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v
