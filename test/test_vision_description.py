"""The user's own camera gantry (issue 50): its lens, screws, camera, dot plate and travel
in one description file, which the vision calibrator and `calibrate vision --bag` take.
The committed vision run (bags/vision_calibration_run: the shipped gantry, 16 and 40
mm/rev screws) is the data; its true screws are within 0.2 % of those."""
from pathlib import Path

import pytest
import yaml

from calib_core.errors import InvalidInputError
from described import changed, refused
from machine_alignment.cli import main as cli_main
from printer_alignment.core.vision_description import read_description
from printer_alignment.nodes.vision_calibrator import DESCRIBED_DEFAULTS

ROOT = Path(__file__).resolve().parents[1]
DESCRIPTIONS = ROOT / 'printer_alignment' / 'descriptions'
SHIPPED = DESCRIPTIONS / 'vision_shipped_simulator.yaml'
USER = DESCRIPTIONS / 'vision_5mm_screws.yaml'
BAG = ROOT / 'bags' / 'vision_calibration_run'


def test_the_shipped_description_is_the_calibrators_defaults():
    """The shipped gantry's description sets vision_calibrator's parameters to their
    defaults, which the node's file (config/, written from the code) holds too."""
    node_file = yaml.safe_load((ROOT / 'config' / 'vision_calibrator.yaml').read_text())
    defaults = node_file['vision_calibrator']['ros__parameters']
    assert read_description(SHIPPED).node_parameters() == DESCRIBED_DEFAULTS
    assert {name: defaults[name] for name in DESCRIBED_DEFAULTS} == DESCRIBED_DEFAULTS
    user = read_description(USER)
    assert user.leads == (0.005, 0.01) and user.image_size == (2448, 2048)


@pytest.mark.parametrize('change, message', [
    ({'kind': 'stage'}, 'kind must be vision'),
    ({'instrument': {'name': 'camera', 'position_sigma_m': 1e-6}},
     'holds geometry and workspace, not instrument'),
    ({'geometry': {'pixel_size_m': 8e-6}}, 'image_size_px must be 2 finite positive'),
    ({'workspace': {'x_range_m': [0.3, 0.0], 'y_range_m': [0.0, 0.25]}}, 'from low to high'),
])
def test_a_bad_description_is_refused_naming_the_key(tmp_path, change, message):
    with pytest.raises(InvalidInputError, match=message):
        read_description(changed(USER, tmp_path, **change))


def test_a_recorded_run_is_solved_against_the_described_lens_and_screws(tmp_path, capsys):
    """The committed run solved against its own gantry's description gives the live run's
    values; described with 5 and 10 mm/rev screws it is refused (not this gantry's
    screws), and described as another camera and plate its dots cannot be indexed."""
    report = tmp_path / 'replay.json'
    assert cli_main(['calibrate', 'vision', '--bag', str(BAG), '--description', str(SHIPPED),
                     '--json', str(report)]) == 0
    assert 'same as the live run: max |difference| 0 ' in capsys.readouterr().out
    geometry = yaml.safe_load(SHIPPED.read_text())['geometry']
    other_screws = changed(SHIPPED, tmp_path, 'screws',
                           geometry={**geometry, 'leads_m_per_rev': [0.005, 0.01]})
    refused(capsys, ['calibrate', 'vision', '--bag', str(BAG), '--description',
                     str(other_screws)], 'the vision calibration failed its sanity checks')
    refused(capsys, ['calibrate', 'vision', '--bag', str(BAG), '--description', str(USER)],
            r'could not be indexed \(wrong pitch or nominal pixel size\?\)')


def test_the_vision_calibrator_takes_the_description(monkeypatch, tmp_path):
    """Started with the 5/10 mm/rev gantry's description, the calibrator holds its lens,
    screws, camera, plate and travel; one of those given beside it is refused."""
    from dds import in_process_node, node_in_process
    from printer_alignment.nodes.vision_calibrator import VisionCalibratorNode
    with node_in_process(VisionCalibratorNode, monkeypatch, tmp_path,
                         description=str(USER)) as node:
        assert {name: node.get_parameter(name).value for name in DESCRIBED_DEFAULTS} \
            == read_description(USER).node_parameters()
        assert (node.nominal_gantry.lead_x, node.nominal_gantry.lead_y) == (0.005, 0.01)
        assert node.plan.x_range == (0.0, 0.3)
    with pytest.raises(InvalidInputError, match='give pitch or description'):
        in_process_node(VisionCalibratorNode, monkeypatch, tmp_path, description=str(USER),
                        pitch=0.001)
