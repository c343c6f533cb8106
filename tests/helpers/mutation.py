"""Hostile values and one-mutation documents for the property tests of input files."""
import copy
import math

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

HOSTILE = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300, 0.0, -1.0, 1e-300, None,
                     True, "", "12 mm", [], {}, [1.0, 2.0], {"value": 1.0}]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-10**6, max_value=10**6),
    st.text(max_size=8),
)
EXAMPLES = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


def _paths(node, prefix=()):
    """Every path (a tuple of keys and indices) to a value inside ``node``, the node itself too."""
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, prefix + (key,))
    elif isinstance(node, list):
        for index, value in enumerate(node):
            yield from _paths(value, prefix + (index,))


def _container(document, path):
    node = document
    for step in path[:-1]:
        node = node[step]
    return node


@st.composite
def mutated(draw, document):
    """``document`` with one random mutation (a deep copy)."""
    out = copy.deepcopy(document)
    paths = [p for p in _paths(out) if p]
    path = draw(st.sampled_from(paths))
    parent, key = _container(out, path), path[-1]
    action = draw(st.sampled_from(["replace", "replace", "replace", "delete", "add"]))
    if action == "replace":
        parent[key] = draw(HOSTILE)
    elif action == "delete":
        del parent[key]
    elif isinstance(parent, dict):
        parent[draw(st.text(min_size=1, max_size=6))] = draw(HOSTILE)
    else:
        parent.append(draw(HOSTILE))
    return out


def refused_in_one_line(load, path):
    """``load(path)``; a ValueError must be one line (anything else raised fails the test).
    Return the result or None if refused."""
    try:
        return load(path)
    except ValueError as error:
        message = str(error)
        assert message and "\n" not in message.strip(), repr(message)
        assert "Traceback" not in message
        return None
