"""``ocalib train --help`` prints the training application's overview without importing Lightning or torch (which
takes seconds), and the overview names exactly the LightningCLI's sub-commands."""

import subprocess
import sys

from ocalib.cli import train


def test_train_help_imports_neither_lightning_nor_torch():
    code = (
        "import sys\n"
        "from ocalib.cli import main\n"
        "rc = main(['train', '--help'])\n"
        "print('rc', rc, sorted({m.split('.')[0] for m in sys.modules} & {'lightning', 'torch', 'pytorch_lightning'}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("usage: ocalib train [-c CONFIG] {fit,validate,test,predict} ...")
    assert out.stdout.rstrip().endswith("rc 0 []"), out.stdout[-300:]


def test_train_alone_prints_the_overview_and_fails(capsys):
    from ocalib.cli import main

    assert main(["train"]) == 1
    assert "ocalib train fit --help" in capsys.readouterr().out


def test_the_overview_names_the_lightning_clis_subcommands():
    from lightning.pytorch.cli import LightningCLI

    assert list(train.SUBCOMMANDS) == list(LightningCLI.subcommands())
    assert all(f"  {name} " in train.help_text() for name in LightningCLI.subcommands())
