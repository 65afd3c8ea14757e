"""compose.yaml: its structure, and the same topology run as local processes so that the file cannot rot; and both
compose files train what ``ennc-ql up`` (``make run``) trains.

Docker does not run on the development machines, so the router service (the ``eclipse/zenoh`` image) is replaced
by ``ennc-ql router`` with the same flags, and the learner and ``replicas`` actors run the compose commands as
they are, except for three rewrites: the router's endpoint becomes a free loopback port, ``/runs`` a temporary
folder, and test-sized budgets are appended (later flags win in argparse).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from actors.config import ActorConfig
from algorithm.policy_file import load_policy
from ennc_ql.cli import build_parser
from learner.config import LearnerConfig
from sim.formulation import Formulation
from tests.e2e import ACTOR_BUDGET, LEARNER_BUDGET, Processes, ennc_ql
from tools.cluster import UP_PRESETS, UpConfig, child_configs
from tools.config import load_config
from tools.system import free_port

pytestmark = pytest.mark.slow

COMPOSE = Path(__file__).resolve().parents[2] / "compose.yaml"
ENDPOINT = re.compile(r"tcp/[A-Za-z0-9.-]+:\d+")
ZENOHD_ONLY = {"--rest-http-port": 1}
"""zenohd flags ``ennc-ql router`` has no use for, with the number of values each takes."""


def compose() -> dict[str, Any]:
    spec: dict[str, Any] = yaml.safe_load(COMPOSE.read_text())
    return spec


def flag_values(argv: list[str], flag: str) -> list[str]:
    """Values of ``flag`` in ``argv``, written either ``--flag value`` or ``--flag=value``."""
    values = [arg.split("=", 1)[1] for arg in argv if arg.startswith(flag + "=")]
    values += [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == flag]
    return values


def test_compose_structure() -> None:
    services = compose()["services"]
    assert set(services) == {"router", "learner", "actor"}

    router = services["router"]
    assert router["image"].split(":")[0] == "eclipse/zenoh"
    assert "7447:7447/tcp" in router["ports"]
    assert flag_values(router["command"], "--listen") == ["tcp/0.0.0.0:7447"]
    assert "--no-multicast-scouting" in router["command"]

    parser = build_parser()
    local_router = parser.parse_args(router_command(router["command"], 7447))
    assert local_router.command == "router" and local_router.listen == ["tcp/127.0.0.1:7447"]
    for name in ("learner", "actor"):
        service = services[name]
        assert service["build"] == "."
        assert service["depends_on"] == ["router"]
        args = parser.parse_args(service["command"])
        assert args.command == name
        assert args.mode == "client"
        assert args.connect == ["tcp/router:7447"]
        assert args.multicast_scouting is False
    learner_args = parser.parse_args(services["learner"]["command"])
    assert str(learner_args.run_dir).startswith("/runs/")
    # A learner that dies comes back by itself and continues from its checkpoint, a limited number of times.
    assert learner_args.resume == "auto" and services["learner"]["restart"] == "on-failure:5"
    assert "runs:/runs" in services["learner"]["volumes"]
    assert services["actor"]["deploy"]["replicas"] >= 2
    # One command line for every replica: the id must be derived at start-up.
    assert flag_values(services["actor"]["command"], "--actor-id") == ["auto"]


def ups_formulation() -> Formulation:
    """What ``ennc-ql up`` (``make run``) gives its learner, and its actors (but for the test-time decision period)."""
    learner, _ = child_configs(load_config(UpConfig, defaults=UP_PRESETS))
    return learner.resolved


@pytest.mark.parametrize("spec", [compose, lambda: secure_compose()], ids=["compose", "compose.secure"])
def test_the_compose_processes_train_ups_formulation(spec: Any) -> None:
    """Every learner and actor resolves, from its compose command as its process does, the formulation up runs."""
    parser = build_parser()
    up = ups_formulation()
    seen = []
    for service in spec()["services"].values():
        if service["command"][0] not in ("learner", "actor"):
            continue  # the router: it carries messages, it learns nothing
        args = parser.parse_args(service["command"])
        config = load_config(LearnerConfig if args.command == "learner" else ActorConfig, args=args)
        mine = config.resolved
        assert mine.names == up.names
        if args.command == "learner":
            assert mine.act_every == up.act_every  # the learner alone evaluates and saves the policy
        seen.append(args.command)
    assert sorted(set(seen)) == ["actor", "learner"]


def assert_trained_ups_formulation(run_dir: Path, actors: list[dict[str, Any]]) -> None:
    """The learner's policy file names up's formulation, and no actor refused a broadcast over another one."""
    up = ups_formulation()
    _, header = load_policy(run_dir / "policy.npz")
    assert (header["featurizer"]["name"], header["reward"]["name"]) == up.names[:2]
    assert header["action_steps"] == up.act_every  # the test-time decision period the learner saved it with
    assert all(a["policies_refused"] == 0 for a in actors)


def local_command(argv: list[str], router_port: int, runs: Path) -> list[str]:
    """A compose command for this machine: every endpoint on the local router, /runs under ``runs``."""
    out = []
    for arg in argv:
        arg = ENDPOINT.sub(f"tcp/127.0.0.1:{router_port}", arg)
        out.append(re.sub(r"(^|=)/runs(?=/|$)", lambda m: m.group(1) + str(runs), arg))
    return out


def router_command(zenohd_argv: list[str], port: int) -> list[str]:
    """``ennc-ql router`` with the zenohd service's flags (listen endpoint moved to loopback)."""
    argv, skip = [], 0
    for arg in zenohd_argv:
        if skip:
            skip -= 1
        elif arg in ZENOHD_ONLY:
            skip = ZENOHD_ONLY[arg]
        else:
            argv.append(ENDPOINT.sub(f"tcp/127.0.0.1:{port}", arg))
    return ["router", *argv]


def test_compose_topology_runs_as_local_processes(tmp_path: Path) -> None:
    services = compose()["services"]
    replicas = services["actor"]["deploy"]["replicas"]
    port = free_port()
    runs = tmp_path / "runs"
    with Processes(tmp_path) as procs:
        procs.start("router", ennc_ql(*router_command(services["router"]["command"], port)))
        learner_argv = local_command(services["learner"]["command"], port, runs)
        procs.start("learner", ennc_ql(*learner_argv, *LEARNER_BUDGET))
        for i in range(replicas):
            procs.start(f"actor-{i}", ennc_ql(*local_command(services["actor"]["command"], port, runs), *ACTOR_BUDGET))

        actors, report = procs.stop_after_first_policy([f"actor-{i}" for i in range(replicas)])
        assert procs.procs["router"].poll() is None, "the router died\n" + procs.log_tail("router")
    assert procs.procs["router"].returncode == 0, "the router did not stop cleanly on SIGTERM"

    run_dir = Path(flag_values(learner_argv, "--run-dir")[0])
    assert (run_dir / "report.json").exists() and (run_dir / "policy.npz").exists()
    # `--actor-id auto` gave every replica its own id, and each one's experience reached the learner's store once.
    assert len(report["actors"]) == replicas
    assert all(a["tuples_sent"] > 0 for a in actors)
    assert sorted(report["tuples_by_actor"].values()) == sorted(a["tuples_sent"] for a in actors)
    assert report["tuples_received"] == sum(a["tuples_sent"] for a in actors)
    assert report["gaps"] == 0
    # Policies went the other way, through the router, to every replica.
    assert report["policy_version"] >= 1
    assert all(a["policy_version"] >= 1 and a["policies_applied"] >= 1 for a in actors)
    assert all(a["outbox"] == 0 for a in actors)  # everything they sent was acknowledged
    assert_trained_ups_formulation(run_dir, actors)


# -- compose.secure.yaml ----------------------------------------------------------------------------------------------

SECURE = COMPOSE.with_name("compose.secure.yaml")
MOUNT = "/run/secrets"


def secure_compose() -> dict[str, Any]:
    spec: dict[str, Any] = yaml.safe_load(SECURE.read_text())
    return spec


def mounted(service: dict[str, Any], secrets: dict[str, Any]) -> dict[str, str]:
    """target file name -> the file under ./secrets it comes from, for every secret ``service`` mounts."""
    out = {}
    for entry in service["secrets"]:
        source = secrets[entry["source"]]["file"]
        assert source.startswith("./secrets/")
        out[entry["target"]] = source.removeprefix("./secrets/")
    return out


def referenced(config: Path) -> set[str]:
    """The files under the mount that a generated zenoh configuration refers to."""
    return set(re.findall(re.escape(MOUNT) + r"/([A-Za-z0-9_.-]+)", config.read_text()))


def test_secure_compose_mounts_for_each_service_exactly_its_own_secrets(tmp_path: Path) -> None:
    from ennc_ql.cli import main

    spec = secure_compose()
    services, secrets = spec["services"], spec["secrets"]
    actors = sorted(name for name in services if name.startswith("actor-"))
    assert (
        main(["secure", "init", str(tmp_path), "--actors", str(len(actors)), "--host", "router", "--mount", MOUNT]) == 0
    )
    parser = build_parser()
    for name, service in services.items():
        files = mounted(service, secrets)
        assert all(target == source for target, source in files.items())  # each file under the name it was made
        assert all((tmp_path / source).exists() for source in files.values())
        args = parser.parse_args(service["command"])
        config = Path(args.zenoh_config)
        assert config.parent == Path(MOUNT) and config.name in files
        # What the process's configuration refers to is mounted, and nothing else: no other identity's key.
        assert set(files) == referenced(tmp_path / config.name) | {config.name}, name
        ident = "learner" if args.command == "learner" else name  # the router's and actors' services are their ids
        assert {f for f in files if f.endswith(".key")} == {f"{ident}.key"}
        if args.command == "actor":
            assert args.actor_id == name
        if args.command == "learner":  # it comes back by itself, as in compose.yaml
            assert args.resume == "auto" and service["restart"] == "on-failure:5"
    router_config = (tmp_path / "router.json5").read_text()
    assert '"tls/0.0.0.0:7447"' in router_config and "7447:7447/tcp" in services["router"]["ports"]
    assert '"tls/router:7447"' in (tmp_path / "learner.json5").read_text()


def test_secure_compose_topology_runs_as_local_processes(tmp_path: Path) -> None:
    from ennc_ql.cli import main

    services = secure_compose()["services"]
    actors = sorted(name for name in services if name.startswith("actor-"))
    port, folder, runs = free_port(), tmp_path / "secrets", tmp_path / "runs"
    assert main(["secure", "init", str(folder), "--actors", str(len(actors)), "--port", str(port)]) == 0

    def local(argv: list[str]) -> list[str]:
        return [
            re.sub(r"(^|=)/runs(?=/|$)", lambda m: m.group(1) + str(runs), a.replace(MOUNT, str(folder))) for a in argv
        ]

    with Processes(tmp_path) as procs:
        # The configuration listens on every interface; the test keeps to loopback (flags override the file).
        procs.start("router", ennc_ql(*local(services["router"]["command"]), "--listen", f"tls/127.0.0.1:{port}"))
        learner_argv = local(services["learner"]["command"])
        procs.start("learner", ennc_ql(*learner_argv, *LEARNER_BUDGET))
        for name in actors:
            procs.start(name, ennc_ql(*local(services[name]["command"]), *ACTOR_BUDGET))
        results, report = procs.stop_after_first_policy(actors)
        assert procs.procs["router"].poll() is None, "the router died\n" + procs.log_tail("router")
    # Each actor's stream reached the learner once and whole, through the authenticating router, and policies
    # came back to every actor.
    assert report["tuples_by_actor"] == {name: r["tuples_sent"] for name, r in zip(actors, results, strict=True)}
    assert all(r["tuples_sent"] > 0 and r["outbox"] == 0 and r["policies_applied"] >= 1 for r in results)
    assert report["gaps"] == 0 and report["rejected_by_type"] == {} and report["rejected"] == 0
    assert_trained_ups_formulation(Path(flag_values(learner_argv, "--run-dir")[0]), results)
