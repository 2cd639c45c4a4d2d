"""The diagnosis report: one self-contained HTML file (:func:`write_report`)."""

from maglevid.report.html import render_report, write_report

__all__ = ["render_report", "write_report"]
