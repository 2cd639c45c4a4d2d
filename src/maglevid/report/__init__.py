"""The diagnosis report: one self-contained HTML file (:func:`write_report`)."""

from maglevid.report.html import render_report, write_report
from maglevid.report.trends import trends_from_history

__all__ = ["render_report", "trends_from_history", "write_report"]
