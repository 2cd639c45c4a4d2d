"""The presets read the real records in shared/data as their READMEs describe them.

Reference values are the READMEs' tables (sample counts, durations, rates,
ranges) and the first rows of the files as printed (exact: the reader must not
change a printed value).
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import FileFormatError
from maglevid.io import read_recording, write_recording

UAQ = "maglev-uaq-levitador"

#: README "Files and columns", table A: samples per session file.
SESSION_FILES = {
    "dataset_constante_20251217_205611.txt": 2989,
    "dataset_escalon_20251217_205858.txt": 2989,
    "dataset_multiescalon_20251217_210203.txt": 3487,
    "dataset_senoidal_20251217_205952.txt": 2884,
    "dataset_chirp_20251217_210058.txt": 3487,
}
#: README table B.
LEGACY_FILES = {"datos_levitador.txt": 7673, "MONIT_SWEEP.txt": 6163}


@pytest.mark.parametrize("name,n", sorted(SESSION_FILES.items()))
@pytest.mark.parametrize("preset", ["uaq-levitador", "uaq-levitador-session"])
def test_uaq_session_files(shared_data, name, n, preset):
    data = read_recording(shared_data / UAQ / name, mapping=preset)
    assert data.n_samples == n and data.dt == 0.01 and data.p == 1
    assert data.names == {"y": ("gap", "i"), "u": ("u",)}
    assert data.units == {"y": ("m", "A"), "u": ("V",)}
    assert data.r is None and data.u_f is None  # yd is not an additive input excitation
    yd = data.metadata["extra_signals"]["yd"]
    assert yd["unit"] == "m" and yd["values"].shape == (n,)
    # u is the PWM command scaled to 0 ... 9.86 V; the gap ADC spans 0 ... 50 mm.
    assert data.u.min() >= 0.0 and data.u.max() <= 9.86
    assert 0.0 <= data.y[:, 0].min() and data.y[:, 0].max() <= 0.05
    assert data.metadata["source_format"] == "text"
    assert any(c.startswith("Ts: 0.01") for c in data.metadata["header_comments"])


def test_uaq_chirp_known_values(shared_data):
    data = read_recording(
        shared_data / UAQ / "dataset_chirp_20251217_210058.txt", mapping="uaq-levitador"
    )
    # First and last rows as printed in the file (t y y_obs dy_obs i u yd).
    assert data.y[0].tolist() == [0.004057, 0.02] and data.u[0, 0] == 0.0
    assert data.y[-1].tolist() == [0.002786, 0.3199] and data.u[-1, 0] == 5.748
    assert data.metadata["extra_signals"]["yd"]["values"][-1] == 0.004204
    assert data.n_samples * data.dt == pytest.approx(34.87, abs=1e-9)  # README: 34.9 s
    assert "Perfil: chirp" in data.metadata["header_comments"]


@pytest.mark.parametrize("name,n", sorted(LEGACY_FILES.items()))
@pytest.mark.parametrize("preset", ["uaq-levitador", "uaq-levitador-legacy"])
def test_uaq_legacy_files(shared_data, name, n, preset):
    data = read_recording(shared_data / UAQ / name, mapping=preset)
    assert data.n_samples == n and data.dt == 0.01 and data.t0 == 0.0
    extras = data.metadata["extra_signals"]
    assert set(extras) == {"yd", "id"} and extras["id"]["unit"] == "A"
    # README: id = -v is clipped to [0, 0.827] A, u to [0, 9.86] V.
    assert extras["id"]["values"].min() >= 0.0 and extras["id"]["values"].max() <= 0.827
    assert data.u.min() >= 0.0 and data.u.max() <= 9.86
    law = data.loop["controller_law"]
    assert (law["outer"]["kp"], law["outer"]["ki"], law["outer"]["kd"]) == (100.0, 50.0, 1.5)
    assert (law["inner"]["kp"], law["inner"]["ki"]) == (12.0, 3000.0)


def test_uaq_legacy_column_order(shared_data):
    # First row "0.0000 0.0050 0.0196 0.8270 0.0444 9.8600" is t, yd, y, id, i, u.
    data = read_recording(shared_data / UAQ / "datos_levitador.txt", mapping="uaq-levitador")
    assert data.y[0].tolist() == [0.0196, 0.0444] and data.u[0, 0] == 9.86
    extras = data.metadata["extra_signals"]
    assert extras["yd"]["values"][0] == 0.005 and extras["id"]["values"][0] == 0.827
    # README: yd = 5 mm (4.5 mm for a while) in this file.
    assert set(np.unique(extras["yd"]["values"])) <= {0.0045, 0.005}


def test_uaq_legacy_time_column_is_checked(shared_data):
    # The time column's steps are 0.0099-0.0101 s (an accumulated sum printed with
    # 4 decimals), i.e. 1 % off dt exactly at the default tolerance; the preset allows
    # 2 %. At 0.5 % the first step outside is reported with its row and line.
    m = {"extends": "uaq-levitador-legacy", "time": {"column": "t", "tolerance": 0.005}}
    with pytest.raises(FileFormatError) as err:
        read_recording(shared_data / UAQ / "datos_levitador.txt", mapping=m)
    assert err.value.column == "t"
    assert "from data row 633 (line 634) to data row 634 (line 635)" in str(err.value)


def test_wrong_uaq_preset_is_a_clear_error(shared_data):
    with pytest.raises(FileFormatError, match=r"names 6 columns .*; the file has 7"):
        read_recording(
            shared_data / UAQ / "dataset_escalon_20251217_205858.txt",
            mapping="uaq-levitador-legacy",
        )


def test_maggy(shared_data):
    path = shared_data / "maggy-ntnu" / "PD_data_with_input.mat"
    data = read_recording(path, mapping="maggy-ntnu")
    assert data.n_samples == 18343 and data.dt == 1 / 2700
    assert data.ny == 9 and data.nu == 2
    assert data.channel_names("y") == tuple(f"s{s}{a}" for s in (1, 2, 3) for a in "xyz")
    assert set(data.units["y"]) == {"mT"} and data.units["u"] == ("count", "count")
    # Values as stored (rawMeasurements1 row 1, u row 5001 in MATLAB indexing); the
    # fields were single precision before MATLAB saved them as double.
    assert data.y[0, :3].tolist() == np.float32([0.0, 0.13, 11.31]).astype(float).tolist()
    assert data.u[5000].tolist() == [pytest.approx(90.6597544, abs=1e-7), 255.0]
    t = data.time
    # README timeline: 0 - 1.26 s u = 0 (the first command is at sample 3391, 1.256 s),
    # magnet resting with s1z about +11 mT; commands within +-255; stable levitation
    # 3 - 6.8 s with s1z about -13.6 mT.
    assert np.all(data.u[t < 1.25] == 0.0) and np.any(data.u[t < 1.26] != 0.0)
    assert data.y[t < 1.25, 2].mean() == pytest.approx(11.0, abs=0.5)
    assert np.abs(data.u).max() <= 255.0
    assert data.y[(t > 3) & (t < 6.8), 2].mean() == pytest.approx(-13.6, abs=0.3)


def test_maggy_without_mapping_says_what_to_do(shared_data):
    path = shared_data / "maggy-ntnu" / "PD_data_with_input.mat"
    with pytest.raises(FileFormatError, match=r"not a maglevid recording.*rawMeasurements1"):
        read_recording(path)


def test_real_record_converts_losslessly(shared_data, tmp_path):
    data = read_recording(shared_data / UAQ / "datos_levitador.txt", mapping="uaq-levitador")
    for name in ("uaq.csv", "uaq.parquet"):
        back = read_recording(write_recording(data, tmp_path / name))
        assert np.array_equal(back.y, data.y) and np.array_equal(back.u, data.u)
        assert back.loop["controller_law"]["kind"] == "cascade-pid-pi"
        assert np.array_equal(
            back.metadata["extra_signals"]["id"]["values"],
            data.metadata["extra_signals"]["id"]["values"],
        )
        assert back.metadata["converted_from"] == str(
            (shared_data / UAQ / "datos_levitador.txt").resolve()
        )
