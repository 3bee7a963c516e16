"""The one way vine_nlp opens a file it reads (TOML, CSV, .npy, meshes, archives).

:func:`open_input` opens without blocking (a FIFO named as a problem file cannot hang the run), refuses anything but a
regular file (FIFOs, devices such as /dev/zero, directories) and a file larger than its limit, all checked on the open
file itself before a byte is parsed. Every failure is one :class:`InputError` ``(named_by, key, reason)``: the file or
argument that named the path. Paths a problem file names may lead anywhere the user can read (``../``, absolute paths):
like a script, a problem file is trusted to name its own data; its content is not.

A file this run is writing (``vine_nlp.io.outputs``) is read from its staged copy."""

from __future__ import annotations

import io
import os
import stat

from vine_nlp.errors import InputError
from vine_nlp.io import limits, outputs


def open_input(path, named_by=None, key="file", limit=limits.MAX_FILE_BYTES, limit_name="MAX_FILE_BYTES"):
    """An open binary file object of the regular file ``path`` of at most ``limit`` bytes."""
    path = str(path)
    own = named_by is None or str(named_by) == path
    where = "" if own else f": {path}"

    def fail(reason):
        return InputError(path if own else named_by, key, reason + where)

    try:
        fd = os.open(outputs.reading(path), os.O_RDONLY | os.O_NONBLOCK)
    except OSError as err:
        raise fail("no such file" if isinstance(err, FileNotFoundError) else f"cannot read ({err.strerror or err})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise fail("is a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file (a pipe, device or socket)")
        if st.st_size > limit:
            raise fail(f"{st.st_size} bytes, more than the limit of {limit} (vine_nlp.io.limits.{limit_name})")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_text(path, named_by=None, key="file", limit=limits.MAX_TOML_BYTES, limit_name="MAX_TOML_BYTES", binary=False):
    """The UTF-8 text (a byte-order mark dropped), or with ``binary`` the bytes, of a regular file of at most ``limit`` bytes."""
    with open_input(path, named_by, key, limit, limit_name) as fh:
        data = fh.read(limit + 1)  # a file that grew since it was opened stops here
    if len(data) > limit:
        raise InputError(path, key, f"more than the limit of {limit} bytes (vine_nlp.io.limits.{limit_name})")
    try:
        return data if binary else data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(path, "file", "not a UTF-8 text file") from None


def text_lines(path, named_by=None, key="file"):
    """(line number, line) of a UTF-8 text file, read as they come: a line longer than
    MAX_LINE_CHARS stops the reading, so memory stays bounded whatever the file holds."""
    fh = open_input(path, named_by, key)
    with io.TextIOWrapper(fh, encoding="utf-8-sig", newline=None) as text:
        number = 0
        try:
            while line := text.readline(limits.MAX_LINE_CHARS + 1):
                number += 1
                if len(line) > limits.MAX_LINE_CHARS and not line.endswith("\n"):
                    raise InputError(path, f"line {number}", f"longer than {limits.MAX_LINE_CHARS} characters (vine_nlp.io.limits.MAX_LINE_CHARS)")
                yield number, line
        except UnicodeDecodeError:
            raise InputError(path, f"line {number + 1}", "not UTF-8 text") from None
