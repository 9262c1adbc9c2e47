"""Tests for ao4d.cli: the command table, common options and how errors end."""

from __future__ import annotations

import pytest

from ao4d import cli


def test_every_command_is_listed_with_help(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert name in text


def test_a_missing_command_module_is_an_error_not_a_silent_gap(monkeypatch):
    # a command module that fails to import raises, rather than vanishing from `ao4d --help`
    monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS + ("nope",))
    with pytest.raises(ModuleNotFoundError, match="ao4d.commands.nope"):
        cli.build_parser()


@pytest.mark.parametrize("name", cli.COMMANDS)
def test_every_command_takes_no_progress(name):
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    assert "--no-progress" in sub.format_help()


def test_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    code = cli.main(["ao", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("ao4d ao: error: ") and "does not exist" in err
    assert err.count("\n") == 1 and "Traceback" not in err


# -- progress -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ball_file(tmp_path_factory):
    import ao4d

    path = tmp_path_factory.mktemp("cli") / "ball.npz"
    ao4d.extract_field(ao4d.fields.hypersphere(1.0), (10,) * 4, (-1.3, 1.3)).save(path)
    return path


def _argv(name, ball, out):
    """A quick run of every command, each doing the kind of work that shows progress."""
    if name == "lift":  # two frames of a ball moving along x
        import trimesh

        out.mkdir(parents=True, exist_ok=True)
        frames = [out / "f0.ply", out / "f1.ply"]
        for k, path in enumerate(frames):
            trimesh.creation.icosphere(1).apply_translation([0.2 * k, 0, 0]).export(path)
        return ["lift", "sweep", *map(str, frames), "--out", str(out / "l.npz")]
    return {
        "demo": ["demo", "--tiny", "--out", str(out / "demo")],
        "info": ["info"],
        "lut": ["lut", "stats", "--dim", "3"],
        "extract": ["extract", "--shape", "hypersphere", "--grid", "8", "--out", str(out / "e.npz")],
        "ao": ["ao", str(ball), "--out", str(out / "a.npz"), "--samples", "4", "--backend", "numpy"],
        "render": [
            "render",
            str(ball),
            "--out",
            str(out / "r.vti"),
            "--size",
            "8",
            "--ao",
            "hits",
            "--samples",
            "4",
            "--light",
            "0",
            "0",
            "0",
            "-1",
            "--shadows",
            "--backend",
            "numpy",
        ],
        "slice": ["slice", str(ball), "--w", "0", "--out", str(out / "s.ply")],
        "view": ["view", str(ball), "--out", str(out / "v.html")],
    }[name]


@pytest.fixture
def eager_progress(monkeypatch):
    """Every piece of work shows progress, and log lines come at once; direct tqdm bars are caught."""
    import tqdm
    import tqdm.auto

    from ao4d import _progress
    from ao4d.rendering import pipeline as rendering

    monkeypatch.setattr(_progress, "LOG_INTERVAL", 0.0)
    monkeypatch.setattr(rendering, "_PROGRESS_VOXELS", 1)
    direct = []

    class Caught(tqdm.tqdm):
        def __init__(self, *args, **kwargs):
            if not kwargs.get("disable") and kwargs.get("file") is None:
                direct.append(kwargs.get("desc"))  # a bar not made by _progress
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(tqdm.auto, "tqdm", Caught)
    monkeypatch.setattr(tqdm, "tqdm", Caught)
    yield direct
    _progress.set_enabled(True)


@pytest.mark.parametrize("name", cli.COMMANDS)
def test_every_command_is_silent_with_no_progress_and_logs_plain_lines(
    name, ball_file, tmp_path, capsys, eager_progress
):
    # render and the demo's render included: no tqdm bars ("primary rays", "shadow rays") and no
    # carriage returns under --no-progress
    argv = _argv(name, ball_file, tmp_path / "quiet")
    assert cli.main(argv[:1] + ["--no-progress"] + argv[1:]) == 0
    err = capsys.readouterr().err
    assert err == "" and not eager_progress, (err, eager_progress)
    assert cli.main(_argv(name, ball_file, tmp_path / "log")) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "\x1b[" not in err and not eager_progress, (err, eager_progress)
    if name == "render":  # the log gets the ray counts as plain lines
        assert "primary rays: " in err and "shadow rays: " in err, err


@pytest.mark.parametrize("port", ["70000", "-1", "65536", "http"])
def test_view_port_out_of_range_is_an_argument_error(port, tmp_path, capsys):
    # socket's OverflowError surfaced as a traceback
    with pytest.raises(SystemExit) as exit_:
        cli.main(["view", str(tmp_path / "s.vti"), "--serve", "--port", port])
    assert exit_.value.code == 2
    assert f"argument --port: must be an integer in 0..65535 (0: any free one), got '{port}'" in capsys.readouterr().err


# -- time estimates from rates measured on this device (ao4d._calibration) --------------------


@pytest.fixture
def calibration(tmp_path, monkeypatch):
    """A fresh calibration cache; ``measure`` counted (its rates are the real ones)."""
    from ao4d import _calibration

    monkeypatch.setenv("AO4D_DATA_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(_calibration, "_memo", {})
    calls = []
    real = _calibration.measure

    def counted(runtime):
        calls.append(runtime)
        return real(runtime)

    monkeypatch.setattr(_calibration, "measure", counted)
    return tmp_path / "cache" / _calibration.CACHE_NAME, calls


def test_ao_and_render_estimates_measure_once_and_keep_the_rates(calibration, ball_file, tmp_path, capsys, monkeypatch):
    import json

    from ao4d import __version__, _calibration

    cache, calls = calibration
    assert cli.main(["ao", str(ball_file), "--samples", "8", "--out", str(tmp_path / "a.npz")]) == 0
    out = capsys.readouterr().out
    assert "timing this device once for the estimates" in out and len(calls) == 1
    assert "with the BVH build (rates measured on this device)" in out
    ((key, entry),) = json.loads(cache.read_text()).items()
    assert key.startswith(f"ao4d {__version__} | ") and entry["ao_rays"] > 0 and entry["bvh"] > 0
    # a later command reads the file: nothing is measured again, not even in a new process
    monkeypatch.setattr(_calibration, "_memo", {})
    assert cli.main(["render", str(tmp_path / "a.npz"), "--out", str(tmp_path / "r.vti"), "--size", "8"]) == 0
    out = capsys.readouterr().out
    assert "timing this device" not in out and len(calls) == 1
    assert "render: 512 voxels, " in out and "(rates measured on this device)" in out


def test_damaged_calibration_cache_is_measured_again(calibration, ball_file, tmp_path, capsys):
    cache, calls = calibration
    cache.parent.mkdir(parents=True)
    cache.write_text("{not json")
    assert cli.main(["ao", str(ball_file), "--samples", "4", "--out", str(tmp_path / "a.npz")]) == 0
    assert len(calls) == 1 and cache.read_text().startswith("{\n")


def test_estimates_scale_with_the_work():
    from ao4d._calibration import Rates, ao_seconds, render_seconds, seconds_text

    r = Rates(bvh=1e6, points=1e6, ao_rays=1e7, voxels=1e7, hits=1e6, setup=1e7, simplices=1e5, device="d", seconds=0.1)
    base = ao_seconds(r, simplices=10**5, points=10**5, rays=64e5)
    assert ao_seconds(r, simplices=10**5, points=10**5, rays=256e5) - base == pytest.approx(192e5 / 1e7)
    assert ao_seconds(r, simplices=10**5, points=10**5, rays=64e5, build=False) == pytest.approx(base - 0.1)
    # a deeper tree: slower rays (by the depth ratio), never faster than measured
    deep = ao_seconds(r, simplices=10**7, points=10**5, rays=64e5, build=False)
    assert deep - 0.1 == pytest.approx(0.64 * 7 / 5)
    shallow = ao_seconds(r, simplices=10**3, points=10**5, rays=64e5, build=False)
    assert shallow - 0.1 == pytest.approx(0.64)
    plain = render_seconds(r, voxels=10**6, hits=10**5, simplices=10**5)
    assert render_seconds(r, voxels=10**6, hits=10**5, simplices=10**5, rays_per_hit=64) - plain == pytest.approx(0.64)
    assert render_seconds(r, voxels=2 * 10**6, hits=10**5, simplices=10**5) - plain == pytest.approx(0.1)
    assert [seconds_text(s) for s in (0.04, 2.44, 75, 7200)] == [
        "about 0.04 s",
        "about 2.4 s",
        "about 75 s",
        "about 2 h",
    ]
