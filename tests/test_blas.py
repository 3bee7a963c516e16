"""One BLAS thread while designing (design.blas): CasADi's private OpenBLAS, NumPy's and SciPy's.

Each case runs in a fresh interpreter: the thread counts are process state, set when a library loads."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from vine_nlp.methods import blas

pytestmark = pytest.mark.skipif(blas.openblas_threads() is None, reason="this CasADi has no private OpenBLAS")

PROBE = r"""
import json, os, sys
import numpy as np
import threadpoolctl
from vine_nlp.methods import blas
import vine_nlp as vn

def counts():
    return sorted({i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"})

out = {"before": counts()}
if sys.argv[1] == "own":
    blas.own_process()
    import scipy.linalg  # loaded after: reads the environment
    out["own"] = counts()
elif sys.argv[1] == "limited":
    with blas.limited():
        out["inside"] = counts()
    out["after"] = counts()
pts = vn.forward([0.3] * 4, [0.8] * 4, [4.0] * 4, 2.43).shape.center
r = vn.design(pts, diameter=2.43, points_per_segment=4)
out["casadi"] = blas.openblas_threads()
out["after_design"] = counts()
out["status"] = r.status
print(json.dumps(out))
"""


def _probe(mode: str, **env) -> dict:
    e = {k: v for k, v in os.environ.items() if k not in blas.ENV_VARS} | env
    p = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, env=e, timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_a_design_sets_casadi_to_one_thread_and_restores_numpys():
    out = _probe("design")
    assert out["status"] == "optimal"
    assert out["casadi"] == 1
    # the registry's context is left: NumPy's threads are the user's again
    assert out["after_design"] == out["before"]


def test_limited_is_one_thread_inside_and_restored_after():
    out = _probe("limited")
    assert out["inside"] == [1]
    assert out["after"] == out["before"]


def test_own_process_sets_loaded_and_later_libraries():
    out = _probe("own")
    assert out["own"] == [1]
    assert out["casadi"] == 1 and out["after_design"] == [1]


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: OpenBLAS's default is one thread anyway")
def test_the_users_choice_wins():
    out = _probe("own", OPENBLAS_NUM_THREADS="2")
    assert out["casadi"] == 2
    assert out["own"] == [2]
