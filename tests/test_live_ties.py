"""mutloc.live.ties: which robots the observations of the last window tie to
the reference (distinct camera-marker pairs, a chain of pairs each tied by
three), checked against hand-counted cases."""

from mutloc.live.ties import TieWindow


def seen(*markers_and_owners):
    return list(markers_and_owners)


def test_one_camera_seeing_two_markers_again_and_again_does_not_tie():
    w = TieWindow("q", window=1.0)
    for k in range(30):
        w.add(k / 30, "p", "p", seen(("M1", "q"), ("M2", "q")))
    assert w.counts(1.0) == {frozenset({"p", "q"}): 2}
    assert w.tied(1.0) == set() and w.ties_of("p", 1.0) == 2


def test_both_cameras_two_markers_each_tie_until_one_is_older_than_the_window():
    w = TieWindow("q", window=1.0)
    w.add(0.0, "q", "q", seen(("M3", "p"), ("M4", "p")))
    w.add(0.5, "p", "p", seen(("M1", "q"), ("M2", "q")))
    assert w.tied(0.9) == {"p"}
    assert w.tied(1.0) == {"p"}  # q's observations exactly a window old still count
    assert w.tied(1.01) == set()  # then only p's two
    w.forget_before(1.01)
    assert w.counts(1.01) == {frozenset({"p", "q"}): 2}


def test_own_markers_and_unknown_owners_are_not_ties():
    w = TieWindow("q", window=1.0)
    w.add(0.0, "p", "p", seen(("M3", "p"), ("M4", "p"), ("X", None), ("M1", "q")))
    assert w.counts(0.0) == {frozenset({"p", "q"}): 1}


def test_cameras_of_one_robot_are_distinct_observations():
    w = TieWindow("q", window=1.0)
    w.add(0.0, "p", "p/front", seen(("M1", "q"), ("M2", "q")))
    w.add(0.1, "p", "p/back", seen(("M1", "q")))
    assert w.tied(0.1) == {"p"}


def test_a_chain_of_strong_pairs_ties_and_a_weak_link_breaks_it():
    w = TieWindow("r0", window=1.0)
    w.add(0.0, "r0", "r0", seen(("A1", "r1"), ("A2", "r1"), ("A3", "r1")))
    w.add(0.0, "r1", "r1", seen(("B1", "r2"), ("B2", "r2"), ("B3", "r2")))
    w.add(0.0, "r2", "r2", seen(("C1", "r3"), ("C2", "r3")))
    assert w.tied(0.5) == {"r1", "r2"}
    w.add(0.4, "r3", "r3", seen(("B1", "r2")))
    assert w.tied(0.5) == {"r1", "r2", "r3"}
