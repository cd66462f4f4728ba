import pytest
from test_train import tiny_config

from clamgen.experiments.train import POLICY_NAME, Trainer


@pytest.fixture(scope="session")
def base_policy(tmp_path_factory):
    """A tiny stage-1 policy file (80 env steps), the frozen base of the stage-2 and
    distillation tests; trained once per session, read only."""
    config = tiny_config(tmp_path_factory.mktemp("base") / "run", total=80)
    Trainer(config).run(show_progress=False)
    return str(config.run_dir / POLICY_NAME)
