"""The fusion rules by name, parsed once into :class:`FusionRule` members.

The per-voxel rules are the C++ core's (``_core.RULE_NAMES``, in the order of its ``Rule``
enum); beside them a network fuses exactly by the channel filter or by source layers. A
member is its name (a ``str``): it prints, joins and serialises as the name, so summaries,
paths and JSON read the same as with plain names.
"""

from __future__ import annotations

from collections.abc import Iterable
from enum import StrEnum

from . import _core

#: the exact fusion modes of a network (not part of "all"): no per-voxel rule of the core
_EXACT_NAMES = ("channel-filter", "source-layers")


class _RuleMethods(StrEnum):
    def __repr__(self) -> str:  # a tuple of rules prints as their names
        return repr(self.value)

    @property
    def core(self) -> _core.Rule | None:
        """The core's per-voxel rule, or None for an exact mode."""
        return _core.Rule.__members__.get(self.name)

    @property
    def exact(self) -> bool:
        """Exact fusion: unclamped maps, no information lost, every agent in one frame."""
        return self.value in _EXACT_NAMES


#: a fusion rule: one of the core's per-voxel rules or an exact mode of a network
FusionRule = _RuleMethods(
    "FusionRule",
    {n.upper().replace("-", "_"): n for n in (*_core.RULE_NAMES, *_EXACT_NAMES)},
    module=__name__,
    qualname="FusionRule",
)

#: the core's per-voxel rules, in the order of its enum ("all")
CORE_RULES: tuple[FusionRule, ...] = tuple(r for r in FusionRule if not r.exact)
#: the exact fusion modes
EXACT_RULES: tuple[FusionRule, ...] = tuple(r for r in FusionRule if r.exact)


def rule_choices() -> tuple[str, ...]:
    """What a list of rules may name: every core rule, 'all', the exact modes."""
    return (*CORE_RULES, "all", *EXACT_RULES)


def parse_rules(value: str | Iterable[str], where: str = "rules") -> tuple[FusionRule, ...]:
    """The rules ``value`` names (a comma-separated text or a list of them; 'all': every
    core rule), in order, each once. ``ValueError`` naming ``where`` and the bad name, with
    the choices."""
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)):
        kind = f"{type(value).__name__} {value!r}"
        raise ValueError(f"{where}: expected a list of fusion rules, got {kind}")
    names: list[FusionRule] = []
    for item in value:
        if isinstance(item, FusionRule):
            names.append(item)
            continue
        for x in str(item).split(","):
            x = x.strip()
            if x == "all":
                names.extend(CORE_RULES)
            elif x in FusionRule._value2member_map_:
                names.append(FusionRule(x))
            elif x:
                raise ValueError(
                    f"{where}: unknown fusion rule {x!r}; valid rules are: "
                    f"{', '.join(CORE_RULES)} (or all), and {' and '.join(EXACT_RULES)}"
                )
    if not names:
        raise ValueError(f"{where}: give at least one fusion rule")
    return tuple(dict.fromkeys(names))
