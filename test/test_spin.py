"""The nodes' shared main block (calib_core.nodes.spin), without DDS."""
import gc
import sys

from rclpy.task import Task

from calib_core.nodes.spin import quiet_half_built_futures


class _Leaky:
    def __del__(self):
        raise ValueError('a different failure')


def _collected(make, capsys) -> str:
    """What stderr shows when an object from ``make`` is collected under the nodes'
    unraisable hook."""
    previous = sys.unraisablehook
    sys.unraisablehook = quiet_half_built_futures
    try:
        thing = make()
        del thing
        gc.collect()
    finally:
        sys.unraisablehook = previous
    return capsys.readouterr().err


def test_a_half_built_rclpy_task_leaves_no_traceback(capsys):
    """A SIGINT while the executor builds a Task leaves one without Future's fields; its
    __del__ raised AttributeError, printed as a traceback on a launched graph's ordered
    stop (a launcher test failed on it once). The nodes' hook drops exactly that."""
    assert 'Traceback' not in _collected(lambda: Task.__new__(Task), capsys)


def test_other_failures_in_a_finaliser_are_still_shown(capsys):
    assert 'a different failure' in _collected(_Leaky, capsys)
