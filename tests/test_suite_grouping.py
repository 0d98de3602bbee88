"""The suite's own set-up: module fixtures shared through xdist groups.

The heavy module fixtures (the demo, the ELFIN chain run, the chain archives) are
computed once only because ``--dist loadgroup`` (pyproject) sends a module's tests to one
worker. pytest 9.2 silently stopped that (pytest-xdist issue 1386: the ``@group`` suffix
of the node ids no longer takes effect); every worker then computed the fixtures
again and the suite took about 2 minutes more. This check makes that loud.
"""

import pytest

pytestmark = pytest.mark.xdist_group("grouping_check")


def test_xdist_groups_are_honoured(request):
    config = request.config
    # on a worker the dist option reads "no"; the controller's come from addopts or argv
    given = " ".join(list(config.getini("addopts"))
                     + list(getattr(config, "workerinput", {}).get("mainargv", [])))
    if not hasattr(config, "workerinput") or "loadgroup" not in given:
        pytest.skip("not run by pytest-xdist with --dist loadgroup")
    assert request.node.nodeid.endswith("@grouping_check"), (
        f"{request.node.nodeid}: xdist groups are not honoured (pytest-xdist issue 1386 "
        "with pytest 9.2); pin pytest below 9.2 in pyproject's test extra")
