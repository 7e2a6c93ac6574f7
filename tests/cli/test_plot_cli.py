"""``lio plot``: trajectories from files and log topics drawn, aligned to the first when asked; every bad input
refused with one line and exit 2 before anything is written."""

import matplotlib.image as mpimg
import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.files.trajectory import format_tum
from lio_cli.jobs.plot import PlotJob, run_plot
from lio_cli.plots.style import DPI
from lio_cli.plots.trajectories import PLOT_FILES, SIZES_IN
from lio_cli.simulation.run import simulate

NS = 1_000_000_000
T0_NS = 1_700_000_000 * NS
MOVE = make_pose(so3_exp(np.array([0.05, -0.02, 1.2])), np.array([3.0, -2.0, 0.5]))
YAW_MOVE = make_pose(so3_exp(np.array([0.0, 0.0, 1.2])), np.array([3.0, -2.0, 0.5]))  # what posyaw can undo


def _walk(n=100):
    t = np.arange(n) * 0.1
    xyz = np.column_stack([np.cos(t), 0.5 * np.sin(2 * t), 0.1 * t])
    return T0_NS + np.arange(n, dtype=np.int64) * (NS // 10), np.stack(
        [make_pose(so3_exp(np.array([0.0, 0.0, 0.3 * a])), p) for a, p in zip(t, xyz)])


@pytest.fixture
def files(tmp_path):
    stamps, poses = _walk()
    a, b, c = tmp_path / "a.tum", tmp_path / "b.tum", tmp_path / "c.tum"
    a.write_text(format_tum(stamps, poses))
    b.write_text(format_tum(stamps, MOVE @ poses))  # the same path in another frame
    c.write_text(format_tum(stamps, YAW_MOVE @ poses))
    return a, b, c


def test_two_files_give_four_pngs_and_one_line_each(files, tmp_path, capsys):
    a, b, _ = files
    out = tmp_path / "plots"
    assert main(["plot", str(a), str(b), "-o", str(out)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [f"wrote {out / name}" for name in PLOT_FILES]
    for name in PLOT_FILES:
        w, h = SIZES_IN[name]
        assert mpimg.imread(out / name).shape[:2] == (round(h * DPI), round(w * DPI))


def test_align_moves_each_trajectory_onto_the_first(files):
    a, b, c = files
    plain = run_plot(PlotJob((str(a), str(b))))
    assert np.abs(plain.tracks[1].positions - plain.tracks[0].positions).max() > 1.0
    for mode, other in (("se3", b), ("sim3", b), ("origin", b), ("posyaw", c)):
        res = run_plot(PlotJob((str(a), str(other)), align=mode))
        first, moved = res.tracks
        np.testing.assert_allclose(moved.positions, first.positions, atol=1e-6)
        np.testing.assert_allclose(moved.poses[:, :3, :3], first.poses[:, :3, :3], atol=1e-6)
        assert moved.name == f"{other} ({mode}-aligned)"
        assert res.notes[0].startswith(f"{other}: aligned to {a} by {mode} over 100 paired poses")


def test_a_log_topic_is_read_as_evaluate_reads_it(tmp_path):
    sim = simulate("handheld", tmp_path / "s.bag", "ros1", duration_s=2.0, seed=1, columns=90)
    res = run_plot(PlotJob((str(sim.gt_path), f"{sim.log_path}:/ground_truth"), align="se3"))
    gt, topic = res.tracks
    assert len(topic) == len(gt) > 100
    np.testing.assert_allclose(topic.positions, gt.positions, atol=1e-6)


@pytest.mark.parametrize("args, message", [
    (["missing.tum"], "lio: error: missing.tum: no such file or folder"),
    (["{a}", "--align", "scale"], "lio: error: Invalid value for '--align': 'scale' is not one of 'none', 'se3', 'sim3', 'posyaw', 'origin'; see 'lio plot --help'"),
    (["{a}", "--times", "{a}", "--rate", "10"], "lio: error: give --times or --rate, not both"),
    (["{a}", "-o", "-"], "lio: error: -o writes PNG files into a folder, not standard output: give -o a path"),
    (["{kitti}"], "lio: error: {kitti}: KITTI poses carry no stamps; give --times FILE (KITTI times.txt) or --rate HZ"),
    (["{a}", "{late}", "--align", "se3"],
     "lio: error: cannot align {late} to {a}: no stamps pair within --t-max-diff 0.01 s "
     "(1700001000.000..1700001009.900 s against 1700000000.000..1700000009.900 s)"),
    (["{a}", "{still}", "--align", "se3"],
     "lio: error: cannot align {still} to {a} by se3: its positions lie on a line or a point; use --align origin or "
     "--align none"),
    (["{a}", "-o", "{a}"], "lio: error: {a}: exists and is not a folder"),
])
def test_bad_input_is_one_line_and_exit_2_with_nothing_written(args, message, files, tmp_path, capsys, monkeypatch):
    a = files[0]
    stamps, poses = _walk()
    kitti = tmp_path / "poses.txt"
    kitti.write_text("".join(" ".join(f"{v:.6f}" for v in p[:3].ravel()) + "\n" for p in poses))
    late = tmp_path / "late.tum"
    late.write_text(format_tum(stamps + 1000 * NS, poses))
    still = tmp_path / "still.tum"
    still.write_text(format_tum(stamps, np.repeat(poses[:1], len(poses), axis=0)))
    names = {"a": a, "kitti": kitti, "late": late, "still": still}
    monkeypatch.chdir(tmp_path)
    assert main(["plot", *(x.format(**names) for x in args)]) == 2
    assert capsys.readouterr().err.strip() == message.format(**names)
    assert not any((tmp_path / name).exists() for name in PLOT_FILES)


def test_existing_pictures_need_force(files, tmp_path, capsys):
    a = files[0]
    (tmp_path / "xyz.png").write_bytes(b"mine")
    assert main(["plot", str(a), "-o", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == f"lio: error: {tmp_path / 'xyz.png'}: already exists; pass --force to overwrite it"
    assert not (tmp_path / "trajectories_xy.png").exists()
    assert main(["plot", str(a), "-o", str(tmp_path), "--force", "-q"]) == 0
    assert (tmp_path / "xyz.png").read_bytes()[:4] == b"\x89PNG"
    assert capsys.readouterr().err == ""


def test_an_interrupt_between_pictures_leaves_neither_pictures_nor_the_folder(files, tmp_path, capsys, monkeypatch):
    # the fuzz round of issue 32: Ctrl-C while drawing left the first PNGs in a folder lio had made
    from lio_cli.plots import trajectories

    def interrupted(tracks):
        raise KeyboardInterrupt

    monkeypatch.setitem(trajectories.FIGURES, PLOT_FILES[-1], interrupted)
    out = tmp_path / "plots"
    assert main(["plot", str(files[0]), "-o", str(out)]) == 130
    assert capsys.readouterr().err.splitlines() == ["lio: interrupted; nothing half-written was left behind"]
    assert not out.exists()


def test_a_sigterm_after_every_picture_is_written_takes_them_back(files, tmp_path, capsys, monkeypatch):
    from lio_cli.cli import app, plot

    def terminated(line, quiet=False):
        raise app.Terminated

    monkeypatch.setattr(plot, "note", terminated)
    out = tmp_path / "plots"
    out.mkdir()
    (out / "mine.txt").write_text("not lio's\n")
    assert main(["plot", str(files[0]), "-o", str(out)]) == 143
    assert capsys.readouterr().err.splitlines() == ["lio: terminated; nothing half-written was left behind"]
    assert sorted(p.name for p in out.iterdir()) == ["mine.txt"]  # a folder lio did not make stays, with its files


def test_an_internal_error_after_the_pictures_takes_them_back(files, tmp_path, capsys, monkeypatch):
    from lio_cli.cli import plot

    def bug(line, quiet=False):
        raise RuntimeError("a bug")

    monkeypatch.setattr(plot, "note", bug)
    out = tmp_path / "plots"
    assert main(["plot", str(files[0]), "-o", str(out)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        "lio: internal error: RuntimeError: a bug (run with --debug for the traceback)"]
    assert not out.exists()
