"""The guide's code is the code: each block a page marks as a file's code equals that file."""

import re

import pytest
from testkit import ROOT

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)

MARKED = re.compile(
    r"<!-- the code of (\S+), kept equal to the file by tests/test_docs_code\.py -->\n\n```python\n(.*?)\n```\n", re.S
)


def marked_blocks(page: str) -> dict[str, str]:
    return dict(MARKED.findall((ROOT / "docs" / page).read_text()))


def test_the_task_guide_shows_both_examples_in_its_raw_markdown():
    assert set(marked_blocks("writing-a-task.md")) == {
        "panda_grasp_env/tasks/put_in_bin.py",
        "docs/examples/shelf_task.py",
    }


@pytest.mark.parametrize("path,code", sorted(marked_blocks("writing-a-task.md").items()))
def test_a_shown_file_equals_the_file(path, code):
    assert code == (ROOT / path).read_text().rstrip("\n"), f"docs/writing-a-task.md shows an old {path}: paste it again"
