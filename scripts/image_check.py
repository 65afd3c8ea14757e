"""The Dockerfile built for real with podman, and compose's topologies trained with its containers: ``make image-test``.

The development machines reach no image registry (nor download.pytorch.org), so:

1. **A base image** stands in for the official Python one: ``debootstrap --variant=minbase bookworm`` with python3
   (3.11) and a virtual environment first on PATH (the ``python`` and ``pip`` the Dockerfile calls), trusting the
   certificate authorities this host trusts, turned into an image with ``podman import``. ``--base IMAGE`` builds on
   an existing image instead.
2. **The image**: ``podman build`` of the Dockerfile as it is, with its build arguments ``BASE`` (the image above)
   and ``TORCH_SOURCE`` (``--find-links`` to the torch wheel this machine's pip takes for pyproject.toml's pin,
   served on loopback); every other package comes from PyPI as for any user. ``--torch-source`` overrides it.
3. **compose.yaml, then compose.secure.yaml**, run as containers of that image, each topology in a pod whose network
   namespace holds nothing but loopback (no host port, no firewall rule), with ``router`` resolving to it: every
   service's command as compose gives it (the plain router, an ``eclipse/zenoh`` image in compose, is ``ennc-ql
   router`` with the same flags) plus short budgets; the learner's named volume on ``/runs``; in the secure run
   every secret bind-mounted read-only at ``/run/secrets/<target>``, as compose mounts file secrets. The secrets
   are written as compose.secure.yaml's header says (``secure init … --host router --mount /run/secrets``), first
   mounted as written (0600, owned by root): the router must stop with a one-line error naming the file; then
   ``chown -R 1000:1000`` as the header says, and the topology must train.

Checked per topology: every container exits 0; each actor's tuples are stored exactly once (the learner's report
against each actor's final status) and acknowledged; policies came back to every actor (version > 0); the run
folder's files belong to the image's user (uid 1000). Exit status 1 if a check fails, 2 if it cannot run.

Everything lives in one temporary folder, podman's storage included (``--root``/``--runroot``), deleted at the end.
Needs root, podman, runc and debootstrap (``apt-get install -y podman runc debootstrap``), PyPI and a Debian mirror::

    .venv/bin/python scripts/image_check.py            # the figures as lines of text
    .venv/bin/python scripts/image_check.py --json     # one JSON object

Over 400 lines: one script that a root machine runs alone, from the base image to the checks of both topologies
(the three steps above and their checks share the temporary folder, podman's storage and the secrets' files).
"""

from __future__ import annotations

import argparse
import functools
import http.server
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from learner.checkpoint import VersionMark

REPO = Path(__file__).resolve().parents[1]
IMAGE = "localhost/ennc-ql:image-check"
BASE_IMAGE = "localhost/ennc-ql-base:bookworm"
VENV = "/opt/python"
"""The base image's virtual environment: the official image's ``python`` and ``pip`` on PATH, installing freely."""
SECRETS_MOUNT = "/run/secrets"
IMAGE_UID = 1000
"""The Dockerfile's user, which the secrets must belong to (compose.secure.yaml's header)."""
CONTAINERS_CONF = """\
# This host's cgroup layout is hybrid (crun refuses it) and root cannot raise limits above the host's hard ones.
[containers]
default_ulimits = ["nofile=4096:4096", "nproc=4096:4096"]
[engine]
runtime = "runc"
cgroup_manager = "cgroupfs"
events_logger = "file"
"""
ZENOHD_ONLY = {"--rest-http-port": 1}
"""Flags of compose's eclipse/zenoh router that ``ennc-ql router`` has no use for, with their value counts."""
# Small budgets, as the end-to-end tests': a first policy within seconds. The durations are only ceilings: the run
# is stopped once POLICIES_BEFORE_STOP policies went out.
LEARNER_BUDGET = [
    *("--duration=600", "--min-tuples=5000", "--phase1-max-patterns=300", "--phase1-n-cycles=10"),
    *("--broadcast-interval=1", "--checkpoint-interval=1", "--eval-interval=1000", "--eval-trials=1"),
    *("--final-eval-trials=2", "--json"),
]
ACTOR_BUDGET = ["--duration=600", "--arenas=16", "--json", "--batch-size=1024", "--flush-timeout=30"]
POLICIES_BEFORE_STOP = 3
"""Policies broadcast (a second apart) before the actors are stopped: every actor has one by then."""
STOP_GRACE_S = {"actor": 60, "learner": 120, "router": 10}
"""SIGTERM to SIGKILL: an actor's outbox flush (--flush-timeout 30), the learner's final evaluation and report."""
RUN_TIMEOUT_S = 300.0


class CheckError(RuntimeError):
    """A step that cannot go on (a tool missing, a build failing): exit status 2."""


def tail(text: str, lines: int = 15) -> str:
    return "\n".join(text.strip().splitlines()[-lines:])


def run(argv: list[str], timeout: float, **kwargs: Any) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, check=False, **kwargs)
    if done.returncode != 0:
        raise CheckError(f"`{' '.join(argv[:4])} ...` exited {done.returncode}:\n{tail(done.stderr + done.stdout)}")
    return done


class Podman:
    """podman on a storage of its own inside ``work`` (the host's images and containers are never touched)."""

    def __init__(self, work: Path) -> None:
        (work / "containers.conf").write_text(CONTAINERS_CONF)
        self.argv = ["podman", "--root", str(work / "storage"), "--runroot", str(work / "runroot")]
        self.env = {**os.environ, "CONTAINERS_CONF": str(work / "containers.conf")}

    def __call__(self, *args: str, timeout: float = 120, **kwargs: Any) -> str:
        return run([*self.argv, *args], timeout, env=self.env, **kwargs).stdout

    def logs(self, container: str) -> tuple[str, str]:
        """What ``container`` wrote on stdout and on stderr."""
        done = subprocess.run(
            [*self.argv, "logs", container], capture_output=True, text=True, timeout=60, env=self.env, check=False
        )
        return done.stdout, done.stderr

    def state(self, container: str) -> tuple[str, int]:
        status, code = self("inspect", container, "--format", "{{.State.Status}} {{.State.ExitCode}}").split()
        return status, int(code)

    def clean(self) -> None:
        """Every pod, container, volume and image of this storage removed (its mounts with them)."""
        for args in (("pod", "rm", "-af"), ("rm", "-af"), ("volume", "rm", "-af"), ("rmi", "-af")):
            subprocess.run([*self.argv, *args], capture_output=True, timeout=300, env=self.env, check=False)


def host_ca_bundle() -> Path:
    """The CA bundle pip trusts here: the host may reach PyPI through a proxy whose CA only it knows."""
    path = Path(os.environ.get("PIP_CERT", "/etc/ssl/certs/ca-certificates.crt"))
    if not path.is_file():
        raise CheckError(f"no CA bundle at {path}: set PIP_CERT to the bundle pip uses here")
    return path


def bootstrap_base(podman: Podman, work: Path, mirror: str) -> str:
    rootfs = work / "rootfs"
    packages = "--include=python3,python3-venv,ca-certificates"
    run(["debootstrap", "--variant=minbase", packages, "bookworm", str(rootfs), mirror], timeout=1800)
    run(["chroot", str(rootfs), "python3", "-m", "venv", VENV], timeout=300)
    shutil.copyfile(host_ca_bundle(), rootfs / "etc/ssl/certs/ca-certificates.crt")
    for deb in (rootfs / "var/cache/apt/archives").glob("*.deb"):
        deb.unlink()
    changes = [
        f"ENV PATH={VENV}/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
        "ENV PIP_CERT=/etc/ssl/certs/ca-certificates.crt",
        'CMD ["python3"]',
    ]
    with subprocess.Popen(["tar", "-C", str(rootfs), "-c", "."], stdout=subprocess.PIPE) as tar:
        podman("import", *(a for c in changes for a in ("--change", c)), "-", BASE_IMAGE, stdin=tar.stdout, timeout=600)
    shutil.rmtree(rootfs)
    return BASE_IMAGE


def torch_pin() -> str:
    dependencies: list[str] = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    return next(d for d in dependencies if d.replace(" ", "").startswith("torch=="))


@contextmanager
def serving(folder: Path) -> Iterator[str]:
    """``folder`` over HTTP on a loopback port (the build runs on the host's network): its URL."""
    handler = functools.partial(QuietHandler, directory=str(folder))
    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler) as server:
        thread = threading.Thread(target=server.serve_forever, name="wheels", daemon=True)
        thread.start()
        try:
            yield f"http://127.0.0.1:{server.server_address[1]}/"
        finally:
            server.shutdown()
            thread.join()


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        """pip's requests are not this script's output."""


def build(podman: Podman, base: str, torch_source: str) -> dict[str, Any]:
    began = time.monotonic()
    podman(
        *("build", "--network", "host", "--build-arg", f"BASE={base}", "--build-arg", f"TORCH_SOURCE={torch_source}"),
        *("-t", IMAGE, "-f", str(REPO / "Dockerfile"), str(REPO)),
        timeout=3600,
    )
    seconds = round(time.monotonic() - began, 1)
    size = int(podman("image", "inspect", IMAGE, "--format", "{{.Size}}"))
    return {"build_s": seconds, "size_bytes": size, "size_gb": round(size / 1e9, 2)}


# -- the topologies -------------------------------------------------------------------------------------------------


@dataclass
class Service:
    """One container: its name, its command (after the image's ENTRYPOINT), what it mounts."""

    name: str
    command: list[str]
    volumes: dict[str, str] = field(default_factory=dict)
    """Named volume -> where it is mounted."""
    files: dict[str, str] = field(default_factory=dict)
    """Host file -> where it is mounted, read-only."""


def router_command(zenohd: list[str]) -> list[str]:
    """``ennc-ql router`` with the flags of compose's eclipse/zenoh router."""
    argv, skip = ["router"], 0
    for arg in zenohd:
        if skip:
            skip -= 1
        elif arg in ZENOHD_ONLY:
            skip = ZENOHD_ONLY[arg]
        else:
            argv.append(arg)
    return argv


def named_volumes(service: dict[str, Any]) -> dict[str, str]:
    return dict(v.split(":", 1) for v in service.get("volumes", []))


def with_budget(command: list[str]) -> list[str]:
    return [*command, *(LEARNER_BUDGET if command[0] == "learner" else ACTOR_BUDGET)]


def plain_services(spec: dict[str, Any]) -> list[Service]:
    services = spec["services"]
    actor = services["actor"]
    return [
        Service("router", router_command(services["router"]["command"])),
        Service("learner", with_budget(services["learner"]["command"]), named_volumes(services["learner"])),
        *(Service(f"actor-{i}", with_budget(actor["command"])) for i in range(actor["deploy"]["replicas"])),
    ]


def secure_services(spec: dict[str, Any], secrets: Path) -> list[Service]:
    out = []
    for name, service in spec["services"].items():
        files = {
            str(secrets / Path(spec["secrets"][s["source"]]["file"]).name): f"{SECRETS_MOUNT}/{s['target']}"
            for s in service["secrets"]
        }
        command = service["command"] if name == "router" else with_budget(service["command"])
        out.append(Service(name, command, named_volumes(service), files))
    return out


def flag(argv: list[str], name: str) -> str:
    return next(a.split("=", 1)[1] for a in argv if a.startswith(name + "="))


class Pod:
    """One topology's containers in a pod of their own: only loopback, shared; ``router`` resolves to it."""

    def __init__(self, podman: Podman, work: Path, name: str) -> None:
        self.podman, self.name = podman, f"ennc-ql-{name}-{os.getpid()}"
        self.hosts = work / f"{name}.hosts"
        self.hosts.write_text("127.0.0.1 localhost router\n")
        self.volumes: set[str] = set()
        podman("pod", "create", "--name", self.name, "--share", "net", "--network", "none")

    def container(self, service: Service) -> str:
        return f"{self.name}-{service.name}"

    def start(self, service: Service) -> None:
        mounts = ["-v", f"{self.hosts}:/etc/hosts:ro"]
        for volume, target in service.volumes.items():
            self.volumes.add(f"{self.name}-{volume}")  # podman creates it, owned as the image's folder it covers
            mounts += ["-v", f"{self.name}-{volume}:{target}"]
        for source, target in service.files.items():
            mounts += ["-v", f"{source}:{target}:ro"]
        self.podman(
            "run", "-d", "--pod", self.name, "--name", self.container(service), *mounts, IMAGE, *service.command
        )

    def exited(self, service: Service) -> int:
        """Once ``service``'s container has exited, its exit status."""
        wait_for(lambda: self.podman.state(self.container(service))[0] == "exited", f"{service.name} to exit")
        return self.podman.state(self.container(service))[1]

    def volume_path(self, volume: str) -> Path:
        return Path(self.podman("volume", "inspect", f"{self.name}-{volume}", "--format", "{{.Mountpoint}}").strip())

    def close(self) -> None:
        self.podman("pod", "rm", "-f", self.name)
        if self.volumes:
            self.podman("volume", "rm", "-f", *self.volumes)


def train(pod: Pod, services: list[Service]) -> dict[str, Any]:
    """Start the router, then the learner and the actors; once policies went out, stop the actors, then the learner
    (SIGTERM, as ``docker compose down``: each actor flushes its outbox, the learner writes its report), then the
    router; the figures and the problems."""
    router, learner, *actors = services
    assert router.command[0] == "router" and learner.command[0] == "learner", "compose's services in another order"
    podman = pod.podman
    pod.start(router)
    wait_for(lambda: "listening on" in podman.logs(pod.container(router))[1], "the router to listen")
    began = time.monotonic()
    for service in (learner, *actors):
        pod.start(service)
    volume, target = next(iter(learner.volumes.items()))
    run_dir = pod.volume_path(volume) / Path(flag(learner.command, "--run-dir")).relative_to(target)
    published = VersionMark(run_dir)  # written (fsynced) before each broadcast
    seen: dict[str, float] = {}

    def policies_out(n: int) -> bool:
        if "learner_started_s" not in seen and "started (policy version 0)" in podman.logs(pod.container(learner))[1]:
            seen["learner_started_s"] = round(time.monotonic() - began, 1)
        if "first_policy_s" not in seen and published.load() >= 1:
            seen["first_policy_s"] = round(time.monotonic() - began, 1)
        return published.load() >= n

    wait_for(lambda: policies_out(POLICIES_BEFORE_STOP), f"{POLICIES_BEFORE_STOP} policies from the learner")
    for service in (*actors, learner, router):  # each stop waits for the exit (SIGKILL past its grace)
        podman("stop", "-t", str(STOP_GRACE_S[service.command[0]]), pod.container(service), timeout=600)
    codes = {s.name: podman.state(pod.container(s))[1] for s in services}
    problems = [f"{name} exited {code}" for name, code in codes.items() if code != 0]
    results = {a.name: last_json(podman.logs(pod.container(a))[0]) for a in actors}
    report = json.loads((run_dir / "report.json").read_text()) if (run_dir / "report.json").exists() else None
    problems += contract(report, results)
    owners = sorted({p.stat().st_uid for p in run_dir.iterdir()}) if run_dir.exists() else []
    if owners != [IMAGE_UID]:
        problems.append(f"the run folder's files belong to uids {owners}, not the image's user {IMAGE_UID}")
    return {
        **seen,
        "exit_codes": codes,
        "tuples_stored": (report or {}).get("tuples_received"),
        "policy_version": (report or {}).get("policy_version"),
        "actors": {
            name: {k: (r or {}).get(k) for k in ("tuples_sent", "policy_version")} for name, r in results.items()
        },
        "problems": problems,
    }


def contract(report: dict[str, Any] | None, results: dict[str, dict[str, Any] | None]) -> list[str]:
    if report is None:
        return ["the learner wrote no report.json"]
    problems = [f"{name} printed no final status" for name, r in results.items() if r is None]
    finals = [r for r in results.values() if r is not None]
    stored = sorted(report["tuples_by_actor"].values())
    if len(report["actors"]) != len(results) or stored != sorted(r["tuples_sent"] for r in finals):
        problems.append(f"stored per actor {report['tuples_by_actor']} != sent {[r['tuples_sent'] for r in finals]}")
    problems += [f"{n} tuples sent" for n in stored if n <= 0]
    if report["gaps"] or report["rejected"]:
        problems.append(f"{report['gaps']} gaps, {report['rejected']} rejected")
    for name, r in results.items():
        if r and (r["outbox"] != 0 or r["tuples_acked"] != r["tuples_sent"]):
            problems.append(f"{name}: {r['tuples_acked']} of {r['tuples_sent']} acknowledged, {r['outbox']} held")
        if r and (r["policy_version"] <= 0 or r["policies_applied"] < 1):
            problems.append(f"{name}: no policy came back (version {r['policy_version']})")
    if report["policy_version"] <= 0:
        problems.append("the learner broadcast no policy")
    return problems


def last_json(stdout: str) -> dict[str, Any] | None:
    lines = stdout.strip().splitlines()
    try:
        return dict(json.loads(lines[-1])) if lines else None
    except json.JSONDecodeError:
        return None


def wait_for(probe: Any, what: str, timeout: float = RUN_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout
    while not probe():
        if time.monotonic() > deadline:
            raise CheckError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.5)


def unreadable_secrets(pod: Pod, router: Service) -> dict[str, Any]:
    """The router on the secrets as ``secure init`` wrote them (0600, root's): it must stop with one line."""
    pod.start(router)
    code = pod.exited(router)
    lines = pod.podman.logs(pod.container(router))[1].strip().splitlines()
    pod.podman("rm", pod.container(router))
    config = flag(router.command, "--zenoh-config")
    one_line = len(lines) == 1 and "Permission denied" in lines[0] and config in lines[0]
    problems = [] if code == 2 and one_line else [f"exit {code}, not one line naming {config}: {lines[-3:]}"]
    return {"exit_code": code, "error": lines[-1] if lines else "", "problems": problems}


def check(args: argparse.Namespace, work: Path) -> dict[str, Any]:
    podman = Podman(work)
    out: dict[str, Any] = {}
    try:
        began = time.monotonic()
        base = args.base or bootstrap_base(podman, work, args.mirror)
        out["base"] = {"image": base, "bootstrap_s": None if args.base else round(time.monotonic() - began, 1)}
        if args.torch_source is not None:
            out["image"] = build(podman, base, args.torch_source)
        else:
            wheels = work / "wheels"
            pip = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:", torch_pin()]
            run([*pip, "-d", str(wheels)], timeout=1800)
            with serving(wheels) as url:
                out["image"] = build(podman, base, f"--find-links {url}")
            shutil.rmtree(wheels)
        plain = yaml.safe_load((REPO / "compose.yaml").read_text())
        pod = Pod(podman, work, "plain")
        try:
            out["plain"] = train(pod, plain_services(plain))
        finally:
            pod.close()
        secure = yaml.safe_load((REPO / "compose.secure.yaml").read_text())
        secrets = work / "secrets"
        actors = sum(name.startswith("actor-") for name in secure["services"])
        init = ["secure", "init", str(secrets), "--actors", str(actors), "--host", "router", "--mount", SECRETS_MOUNT]
        run([sys.executable, "-m", "ennc_ql.cli", *init], timeout=120)
        services = secure_services(secure, secrets)
        pod = Pod(podman, work, "secure")
        try:
            unreadable = unreadable_secrets(pod, services[0])
            run(["chown", "-R", f"{IMAGE_UID}:{IMAGE_UID}", str(secrets)], timeout=60)
            out["secure"] = {**train(pod, services), "unchowned_router": unreadable}
            out["secure"]["problems"] += unreadable.pop("problems")
        finally:
            pod.close()
    finally:
        podman.clean()
    out["passed"] = not out["plain"]["problems"] and not out["secure"]["problems"]
    return out


def lines(out: dict[str, Any]) -> str:
    image = out["image"]
    text = [
        f"base {out['base']['image']}"
        + (f" bootstrapped in {out['base']['bootstrap_s']} s" if out["base"]["bootstrap_s"] else ""),
        f"image built in {image['build_s']} s, {image['size_gb']} GB ({image['size_bytes']} bytes)",
    ]
    for mode in ("plain", "secure"):
        r = out[mode]
        text.append(
            f"{mode}: learner started {r.get('learner_started_s')} s after its container, first policy fitted at "
            f"{r.get('first_policy_s')} s; {r['tuples_stored']} tuples stored, policy v{r['policy_version']}; "
            f"actors {r['actors']}; {'OK' if not r['problems'] else 'FAILED: ' + '; '.join(r['problems'])}"
        )
    if "unchowned_router" in out["secure"]:
        text.append(
            f"secure, secrets not chowned: router exited {out['secure']['unchowned_router']['exit_code']}: "
            f"{out['secure']['unchowned_router']['error']}"
        )
    text.append("PASSED" if out["passed"] else "FAILED")
    return "\n".join(text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", help="build on this image instead of bootstrapping Debian bookworm")
    parser.add_argument("--mirror", default="http://deb.debian.org/debian", help="the Debian mirror of debootstrap")
    parser.add_argument(
        "--torch-source", help="the TORCH_SOURCE build argument (default: the wheel this machine's pip takes)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    missing = [tool for tool in ("podman", "runc", "debootstrap", "chroot", "tar") if shutil.which(tool) is None]
    if os.geteuid() != 0 or missing:
        why = f"missing {', '.join(missing)} (apt-get install -y podman runc debootstrap)" if missing else "needs root"
        print(f"image_check: error: {why}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="ennc-ql-image-") as work:
        try:
            out = check(args, Path(work))
        except CheckError as exc:
            print(f"image_check: error: {exc}", file=sys.stderr)
            return 2
    print(json.dumps(out) if args.json else lines(out))
    return 0 if out["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
