"""Information loss per fusion event and accumulated per agent, and whether the accumulated
loss of a run mostly counts messages (computed from the run's fusion records)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: an accumulated loss "mostly reflects the number of messages" when the messages an agent
#: fused explain at least this share of the spread of accumulated loss across agents (r^2)
MIN_EXPLAINED = 0.5


def event_loss_summary(fusions: Sequence, agents: Sequence[str]) -> dict[str, dict]:
    """Per rule with losses recorded: events, mean and coefficient of variation of the loss
    of one event (nats, summed over its fused voxels), loss per fused voxel, and per agent
    the messages fused and the accumulated loss, with their correlation across agents
    (None when fewer than 3 agents or either does not vary)."""
    out: dict[str, dict] = {}
    for rule in dict.fromkeys(e.rule for e in fusions):
        evs = [e for e in fusions if e.rule == rule and e.loss is not None]
        if not evs:
            continue
        loss = np.array([e.loss for e in evs], dtype=np.float64)
        voxels = sum(e.voxels or 0 for e in evs)
        received = {a: 0 for a in agents}
        accumulated = {a: 0.0 for a in agents}
        for e in evs:
            received[e.receiver] = received.get(e.receiver, 0) + 1
            accumulated[e.receiver] = accumulated.get(e.receiver, 0.0) + e.loss
        mean = float(loss.mean())
        out[rule] = {
            "events": len(evs),
            "mean_loss_per_event": mean,
            "event_loss_cv": float(loss.std() / mean) if mean > 0 else None,
            "loss_per_voxel": float(loss.sum() / voxels) if voxels else None,
            "received": received,
            "accumulated": accumulated,
            "correlation": _correlation(
                [received[a] for a in received], [accumulated[a] for a in received]
            ),
        }
    return out


def _correlation(x, y) -> float | None:
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return None
    return float(np.corrcoef(x, y)[0, 1])


def counts_messages(row: dict) -> bool | None:
    """Whether a rule's accumulated loss mostly reflects the number of messages (None: cannot
    tell, the messages or losses do not vary across agents)."""
    r = row["correlation"]
    return None if r is None else r > 0 and r * r >= MIN_EXPLAINED


def messages_sentence(summary: dict[str, dict]) -> str | None:
    """One sentence on what the accumulated loss of each rule reflects, from the numbers."""
    if not summary:
        return None
    lossless = [r for r, row in summary.items() if row["mean_loss_per_event"] == 0]
    rows = {r: row for r, row in summary.items() if r not in lossless}
    yes = [r for r, row in rows.items() if counts_messages(row)]
    no = [r for r, row in rows.items() if counts_messages(row) is False]
    unknown = [r for r, row in rows.items() if counts_messages(row) is None]

    def explained(names):
        return ", ".join(f"`{r}` {max(0.0, summary[r]['correlation']) ** 2:.0%}" for r in names)

    parts = []
    if yes:
        parts.append(
            "The accumulated loss mostly reflects the number of messages an agent fused: that "
            "number explains this share of the spread of accumulated loss across agents (r^2): "
            + explained(yes)
            + ". Compare agents and rules by the loss per event or per fused "
            "voxel instead."
        )
    if no:
        parts.append(
            (
                "The number of messages explains less of it for "
                if yes
                else "The accumulated loss does not mostly reflect the number of messages: "
                "that number explains less than half of its spread across agents for "
            )
            + explained(no)
            + "."
        )
    if unknown:
        parts.append(
            "For " + ", ".join(f"`{r}`" for r in unknown) + " it cannot be told: "
            "the messages fused or the accumulated losses are the same for every agent "
            "(or fewer than 3 agents)."
        )
    if lossless:
        parts.append(", ".join(f"`{r}`" for r in lossless) + " lost nothing in any fusion.")
    return " ".join(parts)


def markdown_section(summary: dict[str, dict]) -> list[str]:
    """The report's section: a table per rule and the computed sentence."""
    if not summary:
        return []
    lines = [
        "## Information loss per fusion event",
        "",
        "| rule | events | mean loss per event [nats] | CV per event | loss per fused voxel "
        "[nats] | accumulated per agent [nats] | r(accumulated, messages) |",
        "|---|---|---|---|---|---|---|",
    ]
    num = lambda v, f: "–" if v is None else f.format(v)  # noqa: E731
    for r, row in summary.items():
        acc = list(row["accumulated"].values())
        lines.append(
            f"| `{r}` | {row['events']} | {row['mean_loss_per_event']:.4g} | "
            f"{num(row['event_loss_cv'], '{:.2f}')} | "
            f"{num(row['loss_per_voxel'], '{:.4g}')} | "
            f"{np.mean(acc):.4g} (min {min(acc):.4g}, max {max(acc):.4g}) | "
            f"{num(row['correlation'], '{:.2f}')} |"
        )
    lines += [
        "",
        "Loss of one event: the information loss summed over the finest voxels it "
        "fused; accumulated: summed over every event an agent received.",
        "",
    ]
    sentence = messages_sentence(summary)
    if sentence:
        lines += [sentence, ""]
    return lines
