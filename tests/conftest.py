import atexit
import os
import shutil
import tempfile

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vine_nlp.model import shape_lines
from vine_nlp.model.chain import segment_end_samples
from vine_nlp.problem import Routing

# The suite runs the interpreted NLP functions (compiling every structure a test builds would
# take minutes); tests/test_compiled.py turns compiled code on for itself. Never the user's cache.
os.environ["VINE_NLP_CODEGEN"] = os.environ.get("VINE_NLP_TEST_CODEGEN", "off")
os.environ["VINE_NLP_CACHE_DIR"] = tempfile.mkdtemp(prefix="vine_nlp-test-cache-")
atexit.register(shutil.rmtree, os.environ["VINE_NLP_CACHE_DIR"], True)


def model_target(M=12, n=5, D=2.0, seed=0, spam=False, seg_len=2.0):
    """A target made by the forward model: smooth random routing, random pose.

    Returns (points (M n + 1, 3), the true Routing)."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 1, M)
    theta = 0.5 * np.sin(2 * np.pi * (s * rng.uniform(0.5, 1.5) + rng.uniform()))
    lam = np.full(M, 0.7) if spam else 0.7 + 0.2 * np.sin(2 * np.pi * (s + rng.uniform()))
    length = np.full(M, seg_len)
    T0 = np.eye(4)
    T0[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T0[:3, 3] = rng.normal(size=3) * 5
    seg, frac = segment_end_samples(length, n)
    center, _, _ = shape_lines(theta, lam, length, D, seg, frac, T0)
    return center, Routing(theta=theta, lam=lam, length=length, initial_pose=T0)


@pytest.fixture
def make_target():
    return model_target


def mutate(data: dict, index: int, action: str, junk) -> None:
    """Fuzzing helper: replace, delete or misspell the entry picked by ``index`` among all
    nested dict entries of a problem dict (tables inside arrays of tables included)."""
    entries = []

    def walk(d):
        for k, v in d.items():
            entries.append((d, k))
            if isinstance(v, dict):
                walk(v)
            if isinstance(v, list):
                for item in v:
                    if isinstance(item, dict):
                        walk(item)

    walk(data)
    parent, key = entries[index % len(entries)]
    if action == "replace":
        parent[key] = junk
    elif action == "delete":
        del parent[key]
    else:
        parent[f"{key}x"] = junk
