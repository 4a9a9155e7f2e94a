"""The vision calibration in force for the stage graphs' tests, written as vision_calibrator
writes it."""
from calib_core.storage import write_calibration
from printer_alignment.core.vision_calibration import VISION_UNITS
from printer_alignment.sim.camera import CameraOptics
from printer_alignment.sim.gantry import GantryErrors


def vision_in_force(directory):
    """The vision calibration in force, as vision_calibrator writes it (the simulation's
    true camera scale and gantry geometry: this test is about the stage)."""
    camera = CameraOptics().camera2plate
    gantry = {k: float(v) for k, v in GantryErrors().model.as_dict().items()}
    zero = {k: 0.0 for k in gantry}
    write_calibration(directory, 'vision', {
        'kind': 'vision', 'camera2plate': {'pixel_size': float(camera.pixel_size),
                                           'angle': float(camera.angle),
                                           'principal': list(camera.principal)},
        'gantry2plate': gantry,
        'report': {'pixel_size': {'pixel_size_std_m': 0.0, 'angle_std_rad': 0.0},
                   'gantry': {'parameters': gantry, 'std_devs': zero,
                              'units': {k: VISION_UNITS[k] for k in gantry},
                              'residual_rms_m': 0.0,
                              'residual_max_m': 0.0, 'num_positions': 0}}})
