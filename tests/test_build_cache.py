"""The one build cache of the host builds (ns2host.cbuild.cached, content_hash)."""
import hashlib

import pytest

from ns2host.cbuild import cached, content_hash


def test_content_hash_counts_a_file_by_its_name_and_bytes(tmp_path):
    a, b = tmp_path / "a.c", tmp_path / "b.c"
    a.write_bytes(b"int x;")
    b.write_bytes(b"int x;")
    want = hashlib.sha256(b"a.cint x;" + b"-O2" + b"\x00\x01").hexdigest()
    assert content_hash([a, "-O2", b"\x00\x01"], 64) == want
    assert content_hash([a, "-O2", b"\x00\x01"], 16) == want[:16]
    assert content_hash([a], 16) != content_hash([b], 16)           # same bytes, another name
    before = content_hash([b], 16)
    b.write_bytes(b"int y;")
    assert content_hash([b], 16) != before                          # same name, other bytes


@pytest.mark.parametrize("product", ["", "lib.so", None])
def test_a_build_is_made_once_and_put_in_place_whole(tmp_path, product):
    """A folder (complete when it or its product exists) or a file; the second call
    reuses it; no temporary folder stays."""
    final = tmp_path / "cache" / ("entry.elf" if product is None else "entry")
    calls = []

    def build(out):
        calls.append(out)
        (out / (final.name if product is None else (product or "any.o"))).write_text("built")

    assert cached(final, build, product) == final
    assert cached(final, build, product) == final
    assert len(calls) == 1
    got = final if product is None else final / (product or "any.o")
    assert got.read_text() == "built"
    assert sorted(p.name for p in final.parent.iterdir()) == [final.name]


def test_a_failed_build_leaves_nothing(tmp_path):
    final = tmp_path / "entry"

    def build(out):
        (out / "half.o").write_text("half")
        raise RuntimeError("compiler failed")

    with pytest.raises(RuntimeError, match="compiler failed"):
        cached(final, build, "lib.so")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("product", ["lib.so", None])
def test_of_concurrent_builders_the_first_in_place_wins(tmp_path, product):
    """Another process puts its build in place while ours runs: ours is dropped, theirs kept."""
    final = tmp_path / ("entry.elf" if product is None else "entry")

    def build(out):
        if product is None:
            final.mkdir()          # the rename of a file onto a folder fails as onto a finished build
            (out / final.name).write_text("ours")
        else:
            final.mkdir()
            (final / product).write_text("theirs")
            (out / product).write_text("ours")

    if product is None:
        with pytest.raises(OSError):          # final is not the complete file: the failure is not hidden
            cached(final, build, product)
    else:
        assert cached(final, build, product) == final
        assert (final / product).read_text() == "theirs"
    assert sorted(p.name for p in tmp_path.iterdir()) == [final.name]
