"""Files written whole or not at all (vgpl.atomic_write): the shards, proposals, flow caches,
dataset manifests, stage configs and rendered docs all go through it."""

from __future__ import annotations

import pytest

from vgpl.atomic_write import atomic_path


def test_a_write_that_fails_midway_leaves_the_old_file_and_no_temporary_one(tmp_path):
    target = tmp_path / "report.md"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="killed"), atomic_path(target) as tmp:
        tmp.write_text("half of the new")
        assert target.read_text() == "old"  # nothing is in place until the block ends
        raise RuntimeError("killed")
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]


def test_a_finished_write_replaces_the_file_and_makes_its_folder(tmp_path):
    target = tmp_path / "new" / "proposals.h5"
    with atomic_path(target) as first, atomic_path(target) as second:
        assert first != second and first.parent == second.parent == target.parent  # two writers never share a name
        first.write_text("first")
        second.write_text("second")
    assert target.read_text() == "first" and list(target.parent.iterdir()) == [target]  # the outer block ends last
