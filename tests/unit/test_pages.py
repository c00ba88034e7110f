"""core/pages.py: bulk arrays advised into 4 KiB pages where huge pages are slow to fault in."""

from __future__ import annotations

import mmap
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
def test_small_arrays_and_neighbours_keep_their_advice(advice, monkeypatch):
    advice("1")
    real, advised = pages._madvise(), []
    with monkeypatch.context() as m:  # every advice given, recorded (a heap block's flags tell its history, not this array's)
        m.setattr(pages, "_madvise", lambda: lambda start, length, how: advised.append((start, length)) or real(start, length, how))
        pages.zeros(1000, np.uint8)  # below numpy's 4 MiB: never advised, no mapping split
        assert advised == []
        big = np.frombuffer(mmap.mmap(-1, 16_000_000), np.uint8)  # a mapping of its own, with no earlier advice
        view = pages.small_pages(big[4_000_001:12_000_001])  # whole pages inside the view only
    ((start, length),) = advised
    assert view.ctypes.data <= start and start + length <= view.ctypes.data + view.nbytes
    assert "nh" in _vm_flags(view.ctypes.data + 8192)
    assert "nh" not in _vm_flags(big.ctypes.data)
    assert "nh" not in _vm_flags(big.ctypes.data + big.nbytes - 1)
    assert view.base is big


def _numpy_advises_huge_pages() -> bool:
    switch = pages._set_numpy_advice()
    before = switch(True)
    switch(before)
    return bool(before)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="madvise and /proc/self/smaps are Linux's")
def test_numpy_gives_no_huge_page_advice_inside_the_block_and_again_after(advice):
    """A conversion's block (converter.convert, Dask tasks): numpy's own advice off while it runs,
    back after, however blocks of several threads overlap; nothing changes where small pages are not wanted."""
    assert pages._set_numpy_advice() is not None  # numpy 2.4 has the switch
    before = _numpy_advises_huge_pages()
    advice("1")
    with pages.numpy_small_pages():
        assert not _numpy_advises_huge_pages()
        inside = np.zeros(16_000_000, np.uint8)
        inside[:] = 1
        assert "hg" not in _vm_flags(inside.ctypes.data + inside.nbytes // 2)
    assert _numpy_advises_huge_pages() == before
    outside = np.zeros(16_000_000, np.uint8)
    if before and "hg" not in _vm_flags(outside.ctypes.data + outside.nbytes // 2):
        pytest.skip("this kernel takes no huge-page advice (no transparent huge pages)")

    import threading

    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def a():
        with pages.numpy_small_pages():
            a_in.set()
            b_in.wait(10)
        a_out.set()

    def b():
        with pages.numpy_small_pages():
            b_in.set()
            a_out.wait(10)
            seen["after a left"] = _numpy_advises_huge_pages()

    threads = [threading.Thread(target=a), threading.Thread(target=b)]
    threads[0].start()
    a_in.wait(10)
    threads[1].start()
    for t in threads:
        t.join(10)
    assert seen == {"after a left": False}  # b's block still runs: the advice stays off
    assert _numpy_advises_huge_pages() == before  # the last one out restores it
    advice("0")
    with pages.numpy_small_pages():
        assert _numpy_advises_huge_pages() == before  # small pages not wanted: numpy's advice stands
