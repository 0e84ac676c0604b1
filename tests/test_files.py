"""Files are written whole or not at all: images, reports, figures, JSON,
cached references and the validation report, on failing disks and failing
writers.

Oracles: the bytes on disk before and after, and the folder's listing (no
temporary left behind). A full disk and a read-only folder are real tmpfs
mounts where the machine allows it (root, and a kernel that lets it
mount); a writer that fails halfway is monkeypatched everywhere."""

import errno
import os
import subprocess
from pathlib import Path

import numpy as np
import OpenImageIO
import pytest

import mitsuba_whitted.bench
import mitsuba_whitted.cli
import mitsuba_whitted.compare
from conftest import cli, one_line
from mitsuba_whitted.compare import ReferenceCache
from mitsuba_whitted.compare.report import MarkdownReport
from mitsuba_whitted.files import WriteError, replaced_folder
from mitsuba_whitted.imageio import read_image, write_image, write_pixels
from validation.scenes import REPORT_SCENE

FORMATS = ("exr", "png", "jpg", "hdr", "pfm")
OLD = b"an image the user already has\n" * 40
IMAGE = np.linspace(0, 1, 48 * 32 * 3, dtype=np.float32).reshape(48, 32, 3)


def render(*args):
    return cli("render", str(REPORT_SCENE), "-D", "res=16", "-D", "aa=none", *args, timeout=300)


def target_in(folder: Path, name: str, existing: bool) -> Path:
    target = folder / name
    if existing:
        target.write_bytes(OLD)
    return target


def assert_untouched(target: Path, existing: bool, others=()) -> None:
    """The old file has its old bytes, a new one is absent, and nothing
    else (a temporary) is in the folder."""
    if existing:
        assert target.read_bytes() == OLD
    else:
        assert not target.exists()
    assert sorted(p.name for p in target.parent.iterdir()) == sorted(
        [target.name] * existing + list(others))


# ------------------------------------------------------- real disks (tmpfs)

@pytest.fixture
def tmpfs(tmp_path):
    """``mount(name, size)``: a tmpfs of ``size`` at ``tmp_path / name``."""
    mounted = []

    def mount(name: str, size: str = "64k") -> Path:
        folder = tmp_path / name
        folder.mkdir()
        result = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs",
                                 str(folder)], capture_output=True)
        if result.returncode != 0:
            pytest.skip("this machine does not let the tests mount a tmpfs (needs root)")
        mounted.append(folder)
        return folder

    yield mount
    for folder in reversed(mounted):
        subprocess.run(["umount", str(folder)], check=True)


def fill(folder: Path) -> None:
    """Fill the disk of ``folder`` until it is full."""
    with open(folder / "fill", "wb", buffering=0) as filler:
        try:
            while True:
                filler.write(b"\0" * 4096)
        except OSError as error:
            assert error.errno == errno.ENOSPC


@pytest.mark.parametrize("existing", [True, False], ids=["existing", "new"])
@pytest.mark.parametrize("suffix", FORMATS)
def test_an_image_on_a_full_disk_is_not_written(tmpfs, suffix, existing):
    """OpenImageIO on a full disk: its PNG writer reports success, its EXR
    writer's failure was not checked, its JPEG writer ends the process."""
    disk = tmpfs("disk")
    target = target_in(disk, f"x.{suffix}", existing)
    fill(disk)
    with pytest.raises(WriteError, match="no space left on device"):
        write_image(target, IMAGE)
    assert_untouched(target, existing, others=["fill"])


def test_render_on_a_full_disk_is_one_sentence(tmpfs):
    disk = tmpfs("disk")
    target = target_in(disk, "x.png", True)
    fill(disk)
    result = render("-o", str(target))
    assert result.returncode == 2
    assert one_line(result.stderr) == (f"mitsuba-whitted: cannot write '{target}': "
                                       "no space left on device.")
    assert_untouched(target, True, others=["fill"])


@pytest.mark.parametrize("existing", [True, False], ids=["existing", "new"])
def test_render_into_a_read_only_folder_is_one_sentence(tmpfs, existing):
    folder = tmpfs("read-only", "1m")
    target = target_in(folder, "x.png", existing)
    subprocess.run(["mount", "-o", "remount,ro", str(folder)], check=True)
    result = render("-o", str(target))
    assert result.returncode == 2
    assert one_line(result.stderr) == (f"mitsuba-whitted: cannot write '{target}': "
                                       "read-only file system.")
    assert_untouched(target, existing)


# ------------------------------------------------ writers failing halfway

class HalfWriter:
    """An OpenImageIO ``ImageOutput`` that writes half of its pixels' bytes
    to the file it was opened on, then fails the way ``fail`` says (false
    with no reason, as OpenImageIO often does, or an exception)."""

    fail = None

    @classmethod
    def create(cls, name):
        return cls()

    def open(self, name, spec):
        self.file = open(name, "wb")
        return True

    def write_image(self, pixels):
        data = np.ascontiguousarray(pixels).tobytes()
        self.file.write(data[:len(data) // 2])
        self.file.flush()
        if isinstance(self.fail, BaseException):
            raise self.fail
        return False

    has_error = False

    def geterror(self):
        return ""

    def close(self):
        self.file.close()
        return True


@pytest.mark.parametrize("existing", [True, False], ids=["existing", "new"])
@pytest.mark.parametrize("fail", [None, KeyboardInterrupt()], ids=["false", "ctrl-c"])
def test_an_image_writer_failing_halfway_leaves_no_trace(tmp_path, monkeypatch, fail, existing):
    """Nothing changes; the next write, which succeeds, replaces the file
    whole and keeps its permissions (a new file gets the umask's)."""
    monkeypatch.setattr(HalfWriter, "fail", fail)
    monkeypatch.setattr(OpenImageIO, "ImageOutput", HalfWriter)
    target = target_in(tmp_path, "x.exr", existing)
    if existing:
        target.chmod(0o640)
    with pytest.raises(WriteError if fail is None else KeyboardInterrupt) as raised:
        write_image(target, IMAGE)
    if fail is None:
        assert str(raised.value) == (
            f"mitsuba-whitted: cannot write '{target}': OpenImageIO's write_image failed "
            "while encoding it (it gave no reason).")
    assert_untouched(target, existing)

    monkeypatch.undo()
    write_image(target, IMAGE)
    np.testing.assert_array_equal(read_image(target), IMAGE)
    umask = os.umask(0o022)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == (0o640 if existing else 0o666 & ~umask)
    assert [p.name for p in tmp_path.iterdir()] == ["x.exr"]


@pytest.mark.parametrize("name, pixels", [
    ("x.png", IMAGE), ("x.exr", np.zeros((4, 4, 3), np.uint8))], ids=["float-png", "uint8-exr"])
def test_pixels_of_the_wrong_type_for_the_format_leave_the_file_alone(tmp_path, name, pixels):
    target = target_in(tmp_path, name, True)
    with pytest.raises(WriteError) as raised:
        write_pixels(target, pixels)
    stored = "uint8" if name.endswith("png") else "float32"
    assert str(raised.value) == (f"mitsuba-whitted: cannot write '{target}': its pixels are "
                                 f"{pixels.dtype}, and the format stores {stored}.")
    assert_untouched(target, True)


def test_a_symbolic_link_is_written_through_whole(tmp_path, monkeypatch):
    real = target_in(tmp_path, "real.png", True)
    link = tmp_path / "link.png"
    link.symlink_to(real.name)
    monkeypatch.setattr(OpenImageIO, "ImageOutput", HalfWriter)
    with pytest.raises(WriteError):
        write_image(link, IMAGE)
    assert real.read_bytes() == OLD and link.is_symlink()
    monkeypatch.undo()
    write_image(link, IMAGE)
    assert link.is_symlink() and read_image(real).shape == IMAGE.shape
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.png", "real.png"]


@pytest.fixture
def full_disk(monkeypatch):
    """Every file flushed to the disk fails as on a full disk."""
    def no_space(descriptor):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", no_space)


def report_text(report):
    report.write("README.md")


def report_png(report):
    report.image("x.png", IMAGE)


def report_heatmap(report):
    report.heatmap("x.png", IMAGE[..., 0], "error")


@pytest.mark.parametrize("write, name", [(report_text, "README.md"), (report_png, "images/x.png"),
                                         (report_heatmap, "images/x.png")],
                         ids=["text", "image", "heatmap"])
def test_report_files_on_a_full_disk_keep_their_old_bytes(tmp_path, full_disk, write, name):
    report = MarkdownReport(tmp_path, "report")
    target = tmp_path / name
    target.parent.mkdir(exist_ok=True)
    target.write_bytes(OLD)
    with pytest.raises(WriteError, match="no space left on device"):
        write(report)
    assert_untouched(target, True)


def test_a_reference_cache_entry_is_whole_or_absent(tmp_path, full_disk):
    cache = ReferenceCache(tmp_path)
    with pytest.raises(WriteError, match="no space left on device"):
        cache.store("key", {"image": np.ones((4, 4, 3))})
    assert list(tmp_path.iterdir()) == []
    assert cache.load("key") is None


# ---------------------------------------------------- the validation report

def test_validation_keeps_the_old_report_until_the_new_one_is_complete(tmp_path, monkeypatch):
    import validation.run as run

    folder = tmp_path / "report"
    folder.mkdir()
    (folder / "README.md").write_bytes(OLD)
    (folder / "stale.png").write_bytes(OLD)
    monkeypatch.setattr(run, "REPORT", folder)
    monkeypatch.setattr(run, "CACHE", tmp_path / "cache")

    def broken(report, cache, **where):
        report.paragraph("half a report")
        report.write()
        raise RuntimeError("a section failed")

    for name in ("equivalence_section", "report_scene_section", "speed_section",
                 "stability_section", "reference_section"):
        monkeypatch.setattr(run, name, lambda report, cache, **where: None)
    monkeypatch.setattr(run, "machine_section", lambda *args: None)
    monkeypatch.setattr(run, "speed_section", broken)
    with pytest.raises(RuntimeError, match="a section failed"):
        run.main([])
    assert_untouched(folder / "README.md", True, others=["stale.png"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]

    monkeypatch.setattr(run, "speed_section", lambda report, cache, **where: None)
    assert run.main([]) == 0
    assert sorted(p.name for p in folder.iterdir()) == ["README.md"]
    assert (folder / "README.md").read_text().startswith("# Validation")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


@pytest.mark.parametrize("renames, content", [(1, OLD), (2, b"new")],
                         ids=["old-folder-moved-aside", "new-folder-in-place"])
def test_a_folder_swap_interrupted_leaves_one_whole_folder(tmp_path, monkeypatch, renames, content):
    """Ctrl-C right after the old folder is moved aside puts it back; right
    after the new one is in place keeps that and removes the old."""
    folder = tmp_path / "report"
    folder.mkdir()
    (folder / "README.md").write_bytes(OLD)
    done = []

    def rename_then_interrupt(source, destination):
        os.replace(source, destination)
        done.append(destination)
        if len(done) == renames:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with replaced_folder(folder) as new:
            (new / "README.md").write_bytes(b"new")
            monkeypatch.setattr(os, "rename", rename_then_interrupt)
    monkeypatch.undo()
    assert (folder / "README.md").read_bytes() == content
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


# ------------------------------------------- output checked before the work

def blocked(tmp_path) -> Path:
    """A path under a file, where no folder can be made."""
    blocker = tmp_path / "a-file"
    blocker.write_bytes(OLD)
    return blocker


@pytest.mark.parametrize("command", ["render-folder", "render-into-folder", "render-suffix",
                                     "bench", "compare", "render-many"])
def test_the_output_is_checked_before_the_work_starts(tmp_path, monkeypatch, capsys, command):
    def never(*args, **kwargs):
        raise AssertionError("the work started")

    monkeypatch.setattr(mitsuba_whitted.cli.mi, "render", never)
    monkeypatch.setattr(mitsuba_whitted.bench, "run", never)
    monkeypatch.setattr(mitsuba_whitted.compare, "compare_scene", never)
    blocker = blocked(tmp_path)
    argv, problem = {
        "render-folder": (["render", str(REPORT_SCENE), "-o", str(blocker / "x.png")],
                          f"'{blocker}' is a file, not a folder"),
        "render-into-folder": (["render", str(REPORT_SCENE), "-o", str(tmp_path)],
                               f"cannot write '{tmp_path}': it is a folder."),
        "render-suffix": (["render", str(REPORT_SCENE), "-o", str(tmp_path / "x.gif")],
                          "use one of .exr, .hdr, .jpeg, .jpg, .pfm, .png"),
        "bench": (["bench", "--quick", "--json", str(blocker / "b.json")],
                  f"'{blocker}' is a file, not a folder"),
        "compare": (["compare", "--quick", str(REPORT_SCENE), "--out", str(blocker)],
                    "it is a file, not a folder"),
        # It named the image in the folder, after the first render.
        "render-many": (["render-many", str(REPORT_SCENE), "--out", str(blocker)],
                        f"cannot write '{blocker}': it is a file, not a folder."),
    }[command]
    assert mitsuba_whitted.cli.main(argv) == 2
    assert problem in one_line(capsys.readouterr().err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]
