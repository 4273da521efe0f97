"""The package's import: one BLAS thread per process unless the user chose (issue 26)."""
import os
import subprocess
import sys


def _threads_seen(env_value):
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if env_value is not None:
        env["OPENBLAS_NUM_THREADS"] = env_value
    code = ("import pipeline, os, sys; assert 'numpy' not in sys.modules; "
            "print(os.environ['OPENBLAS_NUM_THREADS'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_importing_pipeline_sets_one_blas_thread_before_numpy_loads():
    # the console script imports the package first: OpenBLAS reads the variable when numpy loads it
    assert _threads_seen(None) == "1"


def test_a_users_blas_threads_are_kept():
    assert _threads_seen("4") == "4"
