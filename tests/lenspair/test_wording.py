from lenspair.core.wording import counted


def test_one_is_singular_every_other_count_plural() -> None:
    assert [counted(n, "frame") for n in (0, 1, 2)] == ["0 frames", "1 frame", "2 frames"]
    assert counted(1, "batch", "batches") == "1 batch" and counted(3, "batch", "batches") == (
        "3 batches"
    )
