"""The command line starts at once (issue 57): `machine-align --help` and a subcommand's
own help import only what that subcommand needs, never the closed loop's statistics,
scipy's optimisers or matplotlib; the subcommands listed are the ones the modules
register, with the same one-line help."""
import subprocess
import sys

import pytest

from machine_alignment.cli import COMMANDS, build_parser

HEAVY = ('scipy.stats', 'scipy.optimize', 'matplotlib')


def _imported_after(argv: list) -> list:
    code = ('import sys\nfrom machine_alignment.cli import main\ntry:\n'
            f'    main({argv!r})\nexcept SystemExit:\n    pass\n'
            f'print([m for m in {HEAVY!r} if m in sys.modules])')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=120, check=True)
    return eval(result.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize('argv', [['--help'], ['detect', '--help'], ['analyze', '--help'],
                                  ['analyze', 'hexapod', '--help'], ['calibrate', '--help'],
                                  ['calibrate', 'hexapod', '--help'], ['simulate', '--help'],
                                  ['evaluate', '--help'], ['export', '--help'],
                                  ['launch', '--help'], ['demo', '--help'], ['locate', '--help'],
                                  ['needle', '--help'], ['recover', '--help'],
                                  ['plan', '--help'], ['plan', 'stage', '--help'],
                                  ['compensate', '--help'], ['call', '--help']])
def test_help_imports_no_science_stack(argv):
    """Each subcommand's parser names its work by module (machine_alignment.cli.deferred);
    the defaults a parser shows come from modules that load no optimiser."""
    assert _imported_after(argv) == []


def test_the_listed_subcommands_are_the_registered_ones_with_their_help():
    full = build_parser('all')
    action = next(a for a in full._subparsers._group_actions)
    registered = {choice.dest: choice.help for choice in action._choices_actions}
    assert set(registered) == set(COMMANDS)
    for name, (_, _, help_text) in COMMANDS.items():
        assert ' '.join(registered[name].split()) == ' '.join(help_text.split()), name


@pytest.mark.parametrize('name', sorted(COMMANDS))
def test_every_subcommand_builds_and_shows_its_help(name, capsys):
    with pytest.raises(SystemExit) as end:
        build_parser(name).parse_args([name, '--help'])
    assert end.value.code == 0
    assert f'machine-align {name}' in capsys.readouterr().out
