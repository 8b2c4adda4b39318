"""Structure-aware mutation of parsed YAML/TOML documents for fuzzing our strict file readers."""

from __future__ import annotations

from typing import Any

from hypothesis import strategies as st


def mutate(node: Any, draw: Any) -> Any:
    """One random change somewhere in `node`: a key dropped, retyped, added or mutated deeper."""
    if isinstance(node, dict) and node:
        key = draw(st.sampled_from(sorted(node)))
        out = dict(node)
        choice = draw(st.integers(0, 3))
        if choice == 0:
            del out[key]
        elif choice == 1:
            out[key] = draw(
                st.one_of(
                    st.none(),
                    st.booleans(),
                    st.integers(-(10**6), 10**6),
                    st.floats(allow_nan=True),
                    st.text(max_size=8),
                    st.lists(st.integers(), max_size=3),
                )
            )
        elif choice == 2:
            out[key + "_x"] = 1
        else:
            out[key] = mutate(node[key], draw)
        return out
    if isinstance(node, list) and node:
        i = draw(st.integers(0, len(node) - 1))
        out_list = list(node)
        out_list[i] = mutate(node[i], draw)
        return out_list
    return draw(st.one_of(st.none(), st.text(max_size=5), st.integers(), st.floats(allow_nan=True)))
