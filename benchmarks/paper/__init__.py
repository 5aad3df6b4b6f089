"""The paper wing: section 6 of the paper reproduced (``python -m benchmarks.reproduce_paper``,
:mod:`.reproduce`; its figures: :mod:`.figures`)."""
