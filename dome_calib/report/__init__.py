"""Calibration report: report.json, residuals.npz, plots and the page index.html under ``<bundle>/report/``."""
from dome_calib.report.build import (REPORT_DIR, ReportError, ReportOptions, Residuals, build_report, load_residuals,
                                     write_report)
from dome_calib.report.kept import KEPT_FILES, SessionReport, SyncReport, read_kept, write_kept
from dome_calib.report.previous import previous_section
from dome_calib.report.schema import Report, ToCheck, read_report

__all__ = ["KEPT_FILES", "REPORT_DIR", "Report", "ReportError", "ReportOptions", "Residuals", "SessionReport",
           "SyncReport", "ToCheck", "build_report", "load_residuals", "previous_section", "read_kept", "read_report",
           "write_kept", "write_report"]
