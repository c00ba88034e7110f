"""core/pages.py: bulk arrays advised into 4 KiB pages where huge pages are slow to fault in."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from gigapoint.core import pages


def _vm_flags(addr: int) -> list[str]:
    """The VmFlags of the mapping that holds ``addr`` (/proc/self/smaps)."""
    inside = False
    with open("/proc/self/smaps") as f:
        for line in f:
            head = line.split()[0]
            if "-" in head and not head.endswith(":"):
                lo, hi = (int(v, 16) for v in head.split("-"))
                inside = lo <= addr < hi
            elif inside and head == "VmFlags:":
                return line.split()[1:]
    raise AssertionError(f"no mapping holds {addr:#x}")


@pytest.fixture
def advice(monkeypatch):
    """Set GIGAPOINT_SMALL_PAGES for one test (the decision is cached per process)."""

    def set_to(value: str) -> None:
        monkeypatch.setenv("GIGAPOINT_SMALL_PAGES", value)
        pages._madvise.cache_clear()

    yield set_to
    pages._madvise.cache_clear()


def _balloon(root, name: str, device: str, features: str) -> None:
    d = root / name
    d.mkdir()
    (d / "device").write_text(device + "\n")
    (d / "features").write_text(features + "\n")


def test_free_page_reporting_is_read_from_the_balloon_features(tmp_path):
    (tmp_path / "virtio00").mkdir()  # a device whose files cannot be read: skipped, not the end of the search
    _balloon(tmp_path, "virtio0", "0x0001", "1" * 64)  # a network device: its bit 5 means something else
    assert not pages._balloon_reports_free_pages(tmp_path)
    _balloon(tmp_path, "virtio1", "0x0005", "0110001" + "0" * 57)  # a balloon without reporting (bits 1, 2, 6)
    assert not pages._balloon_reports_free_pages(tmp_path)
    _balloon(tmp_path, "virtio2", "0x0005", "0110011" + "0" * 57)  # bits 1, 2, 5, 6: free page reporting
    assert pages._balloon_reports_free_pages(tmp_path)
    assert not pages._balloon_reports_free_pages(tmp_path / "missing")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="madvise and /proc/self/smaps are Linux's")
@pytest.mark.parametrize("make", ["zeros", "empty", "full"])
def test_bulk_arrays_are_advised_into_small_pages_when_asked(advice, make):
    advice("1")
    args = ((3_000_000,), 7, np.uint32) if make == "full" else ((3_000_000,), np.uint32)
    a = getattr(pages, make)(*args)
    middle = a.ctypes.data + a.nbytes // 2
    assert "nh" in _vm_flags(middle)  # MADV_NOHUGEPAGE
    if make == "full":
        assert (a == 7).all()
    elif make == "zeros":
        assert not a.any()
    advice("0")
    b = getattr(pages, make)(*args)
    assert "nh" not in _vm_flags(b.ctypes.data + b.nbytes // 2)  # numpy's own advice stands


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="madvise and /proc/self/smaps are Linux's")
def test_small_arrays_and_neighbours_keep_their_advice(advice):
    advice("1")
    small = pages.zeros(1000, np.uint8)  # below numpy's 4 MiB: never advised, no mapping split
    assert "nh" not in _vm_flags(small.ctypes.data)
    big = np.zeros(16_000_000, np.uint8)
    view = pages.small_pages(big[4_000_001:12_000_001])  # whole pages inside the view only
    assert "nh" in _vm_flags(view.ctypes.data + 8192)
    assert "nh" not in _vm_flags(big.ctypes.data)
    assert "nh" not in _vm_flags(big.ctypes.data + big.nbytes - 1)
    assert view.base is big
