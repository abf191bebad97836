"""The notebooks' helpers (hbeo.lessons): what they print and draw says what was measured."""
from __future__ import annotations


def _metrics(rule=None, paper=None):
    m = {"classes": list("abcdefghij"), "accuracy": 0.5, "pose_error_deg": {"median": 20.0, "median_sym": 9.0},
         "completion": {"iou": 0.4}, "completion_baseline": {"predicted_class": {"iou": 0.3}},
         "runtime_ms": {"median_per_query": 5.0}}
    if rule:
        m["completion_rule"] = rule
    if paper:
        m["completion_paper"] = paper
    return m


def test_training_summary_names_the_completion_rule_and_the_papers_iou_beside():
    """Notebook 04's summary line: under the never-empty rule it names the rule and gives the paper's rule's IoU
    and empty count on the same queries; under the paper's rule (or an older file) the IoU alone."""
    from hbeo.lessons.training import summary
    line = summary(_metrics({"name": "nonempty", "threshold": 0.25, "fallback": True},
                            {"iou": 0.1, "empty": 7}))
    assert "IoU 0.400 (nonempty rule at 0.25; the paper's rule, >= 0.5: 0.100 with 7 empty; " \
           "the class's mean shape: 0.300)" in line
    assert "chance 0.100" in line and "9.0°" in line
    for m in (_metrics(), _metrics({"name": "paper", "threshold": 0.5, "fallback": False}, {"iou": 0.4, "empty": 7})):
        assert "IoU 0.400 (the class's mean shape: 0.300)" in summary(m)
