"""SLICOT's subspace routines via GNU Octave's ``control`` (``moen4``, ``moesp``, ``n4sid``).

The data go to Octave in a ``.mat`` file; Octave times the identification
itself (``tic``/``toc`` around the call, so the start-up of Octave and the file
transfer are not counted) and writes the poles back. ``moen4`` is SLICOT's
combined method (MOESP for ``A, C``, N4SID for ``B, D``); without ``s`` the
package chooses the horizon ``s = min(2 n, n + 10)`` (8 for ``n = 4``).

Install (Debian): ``apt-get install octave octave-control`` (with an optimised
BLAS, ``libopenblas0``; the reference BLAS alone made ``moen4`` 4x slower here).
"""

from __future__ import annotations

import functools
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.peers import PeerMissing, PeerResult

__all__ = ["available", "identify"]

_SCRIPT = r"""
pkg load control;
load('{data}');
dat = iddata(y, u, 1);
tic;
{call}
t = toc;
p = eig(sys.a);
save('-v7', '{out}', 't', 'p');
"""


@functools.lru_cache(maxsize=1)
def available() -> tuple[bool, str]:
    exe = shutil.which("octave-cli") or shutil.which("octave")
    if exe is None:
        return False, "GNU Octave not found (apt-get install octave octave-control)"
    probe = (
        "v = pkg('list'); c = '';"
        "for k = 1:numel(v), if strcmp(v{k}.name, 'control'), c = v{k}.version; end, end;"
        "printf('%s|%s\\n', version(), c);"
    )
    try:
        r = subprocess.run(
            [exe, "--no-gui", "--norc", "--quiet", "--eval", probe],
            capture_output=True,
            text=True,
            timeout=120,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, f"Octave does not start ({exc})"
    line = [s for s in r.stdout.splitlines() if "|" in s]
    if r.returncode != 0 or not line or not line[-1].split("|")[1]:
        return (
            False,
            "Octave runs but its 'control' package is missing (apt-get install octave-control)",
        )
    ver, ctrl = line[-1].split("|")
    return True, f"GNU Octave {ver}, control {ctrl} (SLICOT)"


def identify(
    y: np.ndarray,
    u: np.ndarray,
    order: int,
    horizon: int | None,
    method: str = "moen4",
    timeout: float = 600.0,
) -> PeerResult:
    """SLICOT ``method`` (``moen4``, ``moesp`` or ``n4sid``) of order ``order``, horizon ``s``."""
    ok, why = available()
    if not ok:
        raise PeerMissing(why)
    import scipy.io

    exe = shutil.which("octave-cli") or shutil.which("octave")
    call = f"sys = {method}(dat, {int(order)}"
    call += f", 's', {int(horizon)});" if horizon else ");"
    with tempfile.TemporaryDirectory(prefix="maglevid-octave-") as tmp:
        data, out = Path(tmp) / "data.mat", Path(tmp) / "out.mat"
        scipy.io.savemat(data, {"y": np.asarray(y, float), "u": np.asarray(u, float)})
        script = _SCRIPT.format(data=data, out=out, call=call)
        r = subprocess.run(
            [str(exe), "--no-gui", "--norc", "--quiet", "--eval", script],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        if not out.exists():
            errors = [x for x in r.stderr.splitlines() if x.startswith("error:")]
            raise RuntimeError(f"Octave {method}: {(errors or [r.stderr.strip()])[0][:300]}")
        res = scipy.io.loadmat(out)
    return PeerResult(
        np.asarray(res["p"], dtype=complex).ravel(),
        inner_time_s=float(res["t"].ravel()[0]),
        info={"s": horizon or min(2 * order, order + 10)},
    )
