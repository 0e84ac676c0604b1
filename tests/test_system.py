"""Fields of Linux's /proc files, which the reports and the bench read."""

from mitsuba_whitted import system
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


def _memory_files(tmp_path, monkeypatch, available_kb: int, limit: str, usage: int):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text(f"MemTotal:  99999999 kB\nMemAvailable:  {available_kb} kB\n")
    (tmp_path / "memory.max").write_text(limit + "\n")
    (tmp_path / "memory.current").write_text(f"{usage}\n")
    monkeypatch.setattr(system, "MEMINFO", str(meminfo))
    monkeypatch.setattr(system, "CGROUP_LIMITS", (
        (str(tmp_path / "memory.max"), str(tmp_path / "memory.current")),))


def test_available_memory_is_the_smaller_of_the_system_and_its_cgroup(tmp_path, monkeypatch):
    _memory_files(tmp_path, monkeypatch, 8 << 20, str(3 << 30), 1 << 30)
    assert system.available_memory() == 2 << 30
    _memory_files(tmp_path, monkeypatch, 1 << 20, str(3 << 30), 1 << 30)
    assert system.available_memory() == 1 << 30


def test_a_cgroup_without_a_limit_leaves_the_system_figure(tmp_path, monkeypatch):
    _memory_files(tmp_path, monkeypatch, 5 << 20, "max", 1 << 30)
    assert system.available_memory() == 5 << 30


def test_an_address_space_limit_leaves_what_the_process_has_not_mapped(tmp_path, monkeypatch):
    """``ulimit -v`` counts every mapping of the process (its size in
    /proc/self/status), whatever the machine has free."""
    _memory_files(tmp_path, monkeypatch, 8 << 20, "max", 0)
    mapped = int(proc_field("/proc/self/status", "VmSize").split()[0]) << 10
    monkeypatch.setattr(system, "address_space_limit", lambda: mapped + (1 << 30))
    assert (1 << 30) - (64 << 20) < system.available_memory() <= 1 << 30
    monkeypatch.setattr(system, "address_space_limit", lambda: mapped // 2)
    assert system.available_memory() == 0
    monkeypatch.setattr(system, "address_space_limit", lambda: None)
    assert system.available_memory() == 8 << 30
