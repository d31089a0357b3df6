"""Calibration report: report.json, residuals.npz, plots and the page index.html under ``<bundle>/report/``."""
from dome_calib.report.build import (REPORT_DIR, ReportError, ReportOptions, Residuals, build_report, load_residuals,
                                     write_report)
from dome_calib.report.previous import previous_section

__all__ = ["REPORT_DIR", "ReportError", "ReportOptions", "Residuals", "build_report", "load_residuals",
           "previous_section", "write_report"]
