"""Message conversions shared by every calibrator node."""
from __future__ import annotations

import json

from alignment_msgs.msg import CalibrationResult


def calibration_result_as_message(kind: str, header, parameters: dict, std_devs: dict,
                                  units: dict, report: dict, rms: float, max_residual: float,
                                  residual_unit: str, num_observations: int,
                                  file_path: str = '', version: int = 0) -> CalibrationResult:
    names = list(parameters)
    return CalibrationResult(
        header=header, kind=kind, success=True, message='ok', names=names,
        values=[float(parameters[n]) for n in names],
        std_devs=[float(std_devs.get(n, 0.0)) for n in names],
        units=[units.get(n, '') for n in names], rms_residual=float(rms),
        max_residual=float(max_residual), residual_unit=residual_unit,
        num_observations=int(num_observations), file_path=file_path, version=int(version),
        report_json=json.dumps(report))


def failed_result(kind: str, header, message: str) -> CalibrationResult:
    return CalibrationResult(header=header, kind=kind, success=False, message=message)
