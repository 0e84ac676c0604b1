"""Fields of Linux's /proc files, which the reports and the bench read."""

from mitsuba_whitted.system import proc_field


def test_a_field_is_read_by_its_whole_name(tmp_path):
    status = tmp_path / "status"
    status.write_text("VmHWMx:\t1 kB\nVmHWM:\t  2048 kB\nmodel name\t: AMD EPYC 9B14\n")
    assert proc_field(str(status), "VmHWM") == "2048 kB"
    assert proc_field(str(status), "model name") == "AMD EPYC 9B14"


def test_a_missing_file_or_field_is_none(tmp_path):
    assert proc_field(str(tmp_path / "absent"), "VmHWM") is None
    (tmp_path / "status").write_text("Name:\tpython\n")
    assert proc_field(str(tmp_path / "status"), "VmHWM") is None
