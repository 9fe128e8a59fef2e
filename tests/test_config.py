import pytest

from cmm.machine import config as cfg


def write(tmp_path, text):
    p = tmp_path / "m.toml"
    p.write_text(text)
    return p


def test_shipped_default_loads_and_converts_units():
    m = cfg.load()
    assert [a.name for a in m.axes] == ["x", "y", "z"]
    assert (m.axis("x").max, m.axis("y").max, m.axis("z").max) == (500.0, 400.0, 300.0)
    z = m.axis("z")
    assert z.to_counts(299.0) == -500 and z.to_mm(-500) == 299.0
    assert m.link.baud == 115200 and m.probe.input == "limit1"




@pytest.mark.parametrize(
    "old, new, message",
    [
        ("counts_per_mm = 500.0\ndirection = 1\nmin = 0.0\nmax = 500.0", "counts_per_mm = -5\ndirection = 1\nmin = 0.0\nmax = 500.0", r"axes.x.counts_per_mm\] must be greater than 0"),
        ("max = 400.0", "max = -1.0", r"travel min 0.0 must be below max -1.0"),
        ('input = "limit1"', 'input = "index"', r"probe.input\] must be limit1 or limit2"),
        ("baud = 115200", "baud = 38400", r"38400 is not available"),
        ("kp = 4000", "kp = 40000", r"gain KP must be 0..32767"),
        ("address = 2", "address = 1", r"each axis needs its own module address"),
        ("stop = 1000.0", "stop = 100.0", r"must stop within 0.2 s"),
        ("probing = 2.0", "probing = nan", r"speeds.probing\] must be a number"),
        ("[speeds]", "[speeds]\nwarp = 9", r"speeds.warp\] is not a known setting"),
    ],
)
def test_bad_values_are_named(tmp_path, old, new, message):
    text = cfg.default_text()
    assert old in text
    with pytest.raises(cfg.ConfigError, match=message):
        cfg.load(write(tmp_path, text.replace(old, new, 1)))


def test_missing_axis_unreadable_and_broken_files(tmp_path):
    with pytest.raises(cfg.ConfigError, match=r"axes.z\] is missing"):
        cfg.load(write(tmp_path, cfg.default_text().split("[axes.z]")[0]))
    with pytest.raises(cfg.ConfigError, match="not valid TOML"):
        cfg.load(write(tmp_path, "[link\nport="))
    with pytest.raises(cfg.ConfigError, match="cannot read"):
        cfg.load(tmp_path / "nope.toml")


def test_per_axis_gain_override(tmp_path):
    text = cfg.default_text().replace("home = 300.0", "home = 300.0\n[axes.z.gains]\nkp = 250")
    m = cfg.load(write(tmp_path, text))
    assert m.axis("z").gains.kp == 250 and m.axis("x").gains.kp == 4000
