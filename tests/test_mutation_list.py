"""``tests/mutations.py`` stays runnable: each bug's text stands once in its file, beside a
test file that exists, under a name given once, and the README counts them. (A change that
rewrites a mutated line would otherwise break the script's run an hour in, at that mutation;
a name given twice silently drops the first of its bugs.)"""

import ast
import collections
import os
import re

import mutations
from mutations import REPO


def test_every_mutation_can_be_written_and_the_readme_counts_them():
    for name, (path, text, replacement, first_file) in mutations.MUTATIONS.items():
        with open(os.path.join(REPO, path)) as file:
            assert file.read().count(text) == 1, f"{name}: its text is not once in {path}"
        assert text != replacement, name
        test_file = first_file.split("::")[0]  # a file, or one test in it
        assert os.path.isfile(os.path.join(REPO, "tests", test_file)), f"{name}: no tests/{test_file}"
    with open(os.path.join(REPO, "README.md")) as file:
        counted = re.findall(r"`python tests/mutations.py` writes (\d+) small", file.read())
    assert counted == [str(len(mutations.MUTATIONS))]


def test_no_mutation_name_is_given_twice():
    with open(mutations.__file__) as file:
        (table,) = [node.value for node in ast.parse(file.read()).body
                    if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", "") == "MUTATIONS"]
    names = collections.Counter(key.value for key in table.keys)
    assert [name for name, count in names.items() if count > 1] == []
