"""Size limits on what vine_nlp reads (archives, problem files, CSV data), in one place.

Each limit keeps one run within about 2 GB of memory on an ordinary machine; input
beyond it is refused with one line naming the limit (``InputError``) instead of
running out of memory or for days. The README lists them ("Limits").
"""

from __future__ import annotations

# Points of one target curve (archives' /target/points, /targets/<k>/points, /measured/points);
# the same as vine_nlp.io.problems.MAX_SAMPLES, so every archive a command writes loads again.
MAX_TARGET_POINTS = 100_000
# Segments of one routing (archives' /runs/<run>/design/*); the same as vine_nlp.io.problems.MAX_SEGMENTS.
# A forward run of that many segments takes about 8 s and stays under 1 GB of address space.
MAX_SEGMENTS = 100_000
# Rows of one modelled line in an archive (/runs/<run>/shape/*): forward runs sample each segment.
MAX_SHAPE_POINTS = 2_000_000
# Runs in one archive, levels of one multi-shape run.
MAX_RUNS = 1_000
MAX_LEVELS = 1_000
# Elements of any other dataset of an archive (measured points, frames, future groups).
MAX_DATASET_ELEMENTS = 10_000_000
# Characters of a text attribute (the archived problem file's source, solver options).
MAX_TEXT_CHARS = 10_000_000
# Bytes of an input file read whole (problem files, CSV point files, archives).
MAX_FILE_BYTES = 1 << 30
