"""A service's plan text and a user's YAML files: numbers written with an exponent and no
dot (``10e-6``, as people and YAML 1.2 write them) are numbers, not strings (PyYAML's YAML
1.1 leaves them strings, and a plan key then fails its check with a confusing message)."""
import pytest
import yaml

from calib_core.errors import InvalidInputError
from calib_core.files import load_yaml, read_yaml
from calib_core.nodes.calibrator import parse_plan


def test_exponents_without_a_dot_are_numbers():
    plan = parse_plan('{target_error: 10e-6, big: 1e3, negative: -2E+2, dotted: 1.5e-3, '
                      'count: 5, name: abc, list: [1e-6, 2]}')
    assert plan == {'target_error': 10e-6, 'big': 1000.0, 'negative': -200.0,
                    'dotted': 1.5e-3, 'count': 5, 'name': 'abc', 'list': [1e-6, 2]}
    assert isinstance(plan['count'], int)


def test_plan_text_that_is_not_a_mapping_or_not_yaml_is_refused(tmp_path):
    with pytest.raises(InvalidInputError, match='mapping'):
        parse_plan('[1, 2]')
    with pytest.raises(yaml.YAMLError):
        load_yaml('{a: [1, 2}')
    geometry = tmp_path / 'geometry.yaml'
    geometry.write_text('stroke: [-5e-3, 5e-3]\n')
    assert read_yaml(geometry, 'a geometry') == {'stroke': [-5e-3, 5e-3]}
