"""memory.release_compiler_pages on mappings of a scratch file standing in for LLVM's library:
clean pages leave the resident set and read back unchanged; a mapping with a private
(copy-on-write) page keeps it."""
import ctypes
import mmap
import sys

import pytest

from mobile_manip_sim.runtime.memory import release_compiler_pages

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps")
SIZE = 64 * mmap.PAGESIZE


def resident_bytes(path) -> int:
    total, inside = 0, False
    with open("/proc/self/smaps") as smaps:
        for line in smaps:
            head = line.split(" ", 1)[0]
            if "-" in head and not head.endswith(":"):
                inside = line.rstrip().endswith(str(path))
            elif inside and head == "Rss:":
                total += int(line.split()[1]) * 1024
    return total


@pytest.fixture
def library(tmp_path):
    path = tmp_path / "libstand_in_for_llvm.so"
    path.write_bytes(bytes(range(256)) * (SIZE // 256))
    return path


def mapped(path, prot):
    with open(path, "r+b") as file:
        return mmap.mmap(file.fileno(), SIZE, flags=mmap.MAP_PRIVATE, prot=prot)


def test_clean_pages_are_released_and_read_back_unchanged(library):
    view = mapped(library, mmap.PROT_READ)
    expected = library.read_bytes()
    assert view[:] == expected and resident_bytes(library) == SIZE
    assert release_compiler_pages(library.name) == SIZE
    assert resident_bytes(library) == 0
    assert view[:] == expected
    view.close()


def test_a_mapping_with_a_copy_on_write_page_is_left_alone(library):
    writable = mapped(library, mmap.PROT_READ | mmap.PROT_WRITE)
    writable[0:4] = b"\xde\xad\xbe\xef"
    read_only = mapped(library, mmap.PROT_READ | mmap.PROT_WRITE)
    read_only[:] = read_only[:]   # every page copied, then made read-only as a loader does
    address = ctypes.addressof(ctypes.c_char.from_buffer(read_only))
    assert ctypes.CDLL(None).mprotect(ctypes.c_void_p(address), SIZE, mmap.PROT_READ) == 0
    resident = resident_bytes(library)
    assert release_compiler_pages(library.name) == 0
    assert resident_bytes(library) == resident
    assert writable[0:4] == b"\xde\xad\xbe\xef"
    assert read_only[:] == library.read_bytes()
