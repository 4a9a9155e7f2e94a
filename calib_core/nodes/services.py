"""The services an operator calls on the calibrators and the aligner, by name: the one list
`machine-align call` offers and the nodes serve (a test checks every such service a node
creates is here). The hardware simulators' services (moves, captures) are not in it.

name -> (service type name in alignment_msgs or std_srvs, progress topic or None, what the
YAML argument is: 'plan', 'options', 'method', 'model' or 'nothing')."""

OPERATOR_SERVICES = {
    'vision_calibrator/calibrate': ('RunCalibration', '/vision_calibrator/progress', 'plan'),
    'vision_calibrator/calibrate_pixel_size': ('RunCalibration', '/vision_calibrator/progress',
                                               'plan'),
    'vision_calibrator/calibrate_intrinsics': ('RunCalibration', '/vision_calibrator/progress',
                                               'plan'),
    'stage_calibrator/calibrate': ('RunCalibration', '/stage_calibrator/progress', 'plan'),
    'hexapod_calibrator/calibrate': ('RunCalibration', '/hexapod_calibrator/progress', 'plan'),
    'grid_calibrator/calibrate': ('RunCalibration', '/grid_calibrator/progress', 'plan'),
    'platform_calibrator/calibrate': ('RunCalibration', '/platform_calibrator/progress', 'plan'),
    'platform_calibrator/register': ('RegisterScreen', None, 'method'),
    'five_axis_calibrator/calibrate': ('RunCalibration', '/five_axis_calibrator/progress',
                                       'plan'),
    'five_axis_calibrator/measure_needle': ('MeasureNeedle', None, 'plan'),
    'five_axis_calibrator/locate': ('LocateWorkpiece', None, 'plan'),
    # The operator's answer to a placement request: the plate lies as asked.
    'grid_calibrator/confirm_placement': ('Trigger', None, 'nothing'),
    'vision_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),
    'stage_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),
    'hexapod_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),
    'platform_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),
    'grid_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),
    'five_axis_calibrator/analyze_residuals': ('AnalyzeResiduals', None, 'options'),
    'aligner/align': ('Align', None, 'model'),
}
# Every calibrator's cancel: its run (calibration or analysis) stops before the next move.
OPERATOR_SERVICES.update({f'{node}/cancel': ('Trigger', None, 'nothing') for node in (
    'vision_calibrator', 'stage_calibrator', 'hexapod_calibrator', 'grid_calibrator',
    'platform_calibrator', 'five_axis_calibrator')})
