"""Run a piece of Python against one checkout's build, in a process of its own: the scripts that
compare this tree with another (bench_bind, bench_split, check_split_identity) measure and read
each tree this way, so that the two builds never share a process."""
import json
import os
import subprocess
import sys


def run_child(checkout: str, code: str, *args: str) -> dict:
    """Runs `code` with `checkout`'s python/ first on the path and `args` as its argv; returns the
    JSON object its last line of output prints. Exits with the child's error when it fails."""
    env = dict(os.environ, PYTHONPATH=os.path.join(checkout, "python"))
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True)
    if out.returncode:
        sys.exit(f"{checkout}: {out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])
