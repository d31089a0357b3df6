"""Calibration report: report.json and plots under ``<bundle>/report/``."""
from dome_calib.report.build import (REPORT_DIR, ReportError, ReportOptions, Residuals, build_report,
                                     load_residuals, write_report)

__all__ = ["REPORT_DIR", "ReportError", "ReportOptions", "Residuals", "build_report", "load_residuals",
           "write_report"]
