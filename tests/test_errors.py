"""errors.about: an InputError from a stage that does not know the file gets the file's name."""

from __future__ import annotations

import pytest

from scan2terrain.errors import InputError, about


def test_about_names_the_file_and_where_in_it() -> None:
    with pytest.raises(InputError) as caught, about("scans.bag", "/scan at 3.000: "):
        raise InputError(None, "a point lies outside the octree")
    assert str(caught.value) == "scans.bag: /scan at 3.000: a point lies outside the octree"
    assert caught.value.problem == "/scan at 3.000: a point lies outside the octree"
    assert isinstance(caught.value.__cause__, InputError)


def test_about_lets_other_errors_through() -> None:
    with pytest.raises(KeyError), about("scans.bag"):
        raise KeyError("a bug of ours stays one")


def test_shown_escapes_what_a_terminal_would_obey() -> None:
    from scan2terrain.errors import shown

    assert shown("/scan") == "/scan"
    assert shown("/scän") == "/scän"  # printable: kept
    assert shown("/s\x1dc\nan\t\x00") == "/s\\x1dc\\nan\\t\\x00"
    assert len(shown("a\u2028b\x85c").splitlines()) == 1
