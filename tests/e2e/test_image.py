"""The Dockerfile's image, replayed without Docker, runs every command compose.yaml starts.

Docker does not run on the development machines, and ``test_compose.py`` runs compose's commands from the dev
install, which sees the whole source tree. This test rebuilds what the image would hold instead: the Dockerfile's
COPY/ADD instructions are replayed from the build context (the repository minus what ``.dockerignore`` keeps out)
into an empty folder that stands for the image's ``/``; the tree its ``pip install`` names is installed, not
editable, into a fresh virtual environment; and every command of a compose service built from this Dockerfile (its
``entrypoint`` and ``command``, or the image's ENTRYPOINT and CMD) starts there with ``--help`` from a folder
outside the repository, its modules imported from the environment's site-packages.

Installing torch, zenoh and rerun again would take minutes, so the project is installed with ``--no-deps`` and the
dev environment's third-party packages are put on the fresh environment's path (a view of its site-packages without
the project's editable hook or metadata): the project's own packages come only from the replayed copy, which is
what catches a package folder that the image does not get.
"""

from __future__ import annotations

import functools
import json
import os
import posixpath
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
DOCKERFILE = REPO / "Dockerfile"
DOCKERIGNORE = REPO / ".dockerignore"
COMPOSE = REPO / "compose.yaml"
PYPROJECT = REPO / "pyproject.toml"
DIST_NAME = "ennc_ql"  # pyproject's project.name, normalized as in dist-info folder names

# ---------------------------------------------------------------------------------------------------------------
# .dockerignore: moby's patternmatcher (what `docker build` and compose use)


def ignore_regex(pattern: str) -> re.Pattern[str]:
    """A .dockerignore pattern as moby compiles it: ``**`` any number of folders, ``*`` and ``?`` within one."""
    regex, i = "", 0
    while i < len(pattern):
        char = pattern[i]
        if pattern.startswith("**", i):
            i += 2
            if pattern.startswith("/", i):
                i += 1
            regex += ".*" if i == len(pattern) else "(.*/)?"
            continue
        if char == "*":
            regex += "[^/]*"
        elif char == "?":
            regex += "[^/]"
        elif char == "[" and "]" in pattern[i + 1 :]:
            end = pattern.index("]", i + 1)
            regex += pattern[i : end + 1]
            i = end
        elif char == "\\" and i + 1 < len(pattern):
            regex += re.escape(pattern[i + 1])
            i += 1
        else:
            regex += re.escape(char)
        i += 1
    return re.compile(f"^{regex}$")


def ignore_patterns(text: str) -> list[tuple[bool, re.Pattern[str]]]:
    """(is an ``!`` exception, regex) per line, cleaned as moby's ignorefile.ReadAll does."""
    patterns = []
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        exception = line.startswith("!")
        if exception:
            line = line[1:].strip()
        if not line:
            continue
        line = posixpath.normpath(line).lstrip("/") or "."
        patterns.append((exception, ignore_regex(line)))
    return patterns


def ignored(path: str, patterns: list[tuple[bool, re.Pattern[str]]]) -> bool:
    """Whether the context path ``path`` is left out: the last pattern matching it or one of its folders decides."""
    parts = path.split("/")
    candidates = ["/".join(parts[: i + 1]) for i in range(len(parts))]
    left_out = False
    for exception, regex in patterns:
        if any(regex.match(candidate) for candidate in candidates):
            left_out = not exception
    return left_out


@dataclass
class Context:
    """The build context: the files (and symbolic links) and folders of ``root`` that .dockerignore lets through."""

    root: Path
    files: set[str] = field(default_factory=set)
    dirs: set[str] = field(default_factory=set)

    @classmethod
    def of(cls, root: Path, dockerignore: str) -> Context:
        patterns = ignore_patterns(dockerignore)
        may_reinclude = any(exception for exception, _ in patterns)
        context = cls(root)
        for dirpath, dirnames, filenames in os.walk(root):
            rel = Path(dirpath).relative_to(root).as_posix()
            prefix = "" if rel == "." else rel + "/"
            walked = []
            for name in dirnames:
                path = prefix + name
                if (Path(dirpath) / name).is_symlink():
                    filenames.append(name)
                elif not ignored(path, patterns):
                    context.dirs.add(path)
                    walked.append(name)
                elif may_reinclude:
                    walked.append(name)  # an exception may bring back something inside
            dirnames[:] = walked
            context.files.update(prefix + name for name in filenames if not ignored(prefix + name, patterns))
        for path in context.files:  # folders holding re-included files are in the context too
            parts = path.split("/")[:-1]
            context.dirs.update("/".join(parts[: i + 1]) for i in range(len(parts)))
        return context

    def sources(self, source: str) -> list[str]:
        """What a COPY source names: context paths (``.`` the whole context), wildcards expanded."""
        clean = posixpath.normpath(source).lstrip("/") or "."
        assert not clean.startswith(".."), f"COPY source {source!r} is outside the build context"
        if re.search(r"[*?\[]", clean):
            regex = ignore_regex(clean.replace("**", "*"))
            return sorted(path for path in self.files | self.dirs if regex.match(path))
        if clean == "." or clean in self.files or clean in self.dirs:
            return [clean]
        return []

    def files_under(self, source: str) -> list[str]:
        if source == ".":
            return sorted(self.files)
        return sorted(path for path in self.files if path.startswith(source + "/"))


# ---------------------------------------------------------------------------------------------------------------
# The Dockerfile


@dataclass
class Instruction:
    keyword: str
    args: str
    line: int


def instructions(text: str) -> list[Instruction]:
    """The Dockerfile's instructions, continuation lines joined and comments dropped (escape character ``\\``)."""
    directives = re.findall(r"^#\s*escape\s*=\s*(\S)", text, flags=re.MULTILINE | re.IGNORECASE)
    assert directives in ([], ["\\"]), "the replay reads only Dockerfiles whose escape character is \\"
    result, pending, start = [], "", 0
    for number, raw in enumerate(text.splitlines(), 1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue  # comments and empty lines, also inside a continued instruction
        if not pending:
            start = number
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        keyword, _, args = (pending + stripped).partition(" ")
        result.append(Instruction(keyword.upper(), args.strip(), start))
        pending = ""
    assert not pending, "the Dockerfile ends inside a continued instruction"
    return result


def exec_form(args: str) -> list[str] | None:
    """The argument list of an instruction in JSON (exec) form, or None for the shell form."""
    if not args.startswith("["):
        return None
    try:
        value = json.loads(args)
    except json.JSONDecodeError:
        return None
    assert isinstance(value, list) and all(isinstance(v, str) for v in value), f"bad JSON form: {args}"
    return value


PIP_VALUE_OPTIONS = {
    *("-r", "--requirement", "-c", "--constraint", "-e", "--editable", "-i", "--index-url", "--extra-index-url"),
    *("-f", "--find-links", "-t", "--target", "--prefix", "--root", "--src", "--upgrade-strategy", "--python"),
    *("--platform", "--python-version", "--implementation", "--abi", "--no-binary", "--only-binary", "--report"),
    *("-C", "--config-settings", "--global-option", "--progress-bar", "--log", "--proxy", "--retries"),
    *("--timeout", "--exists-action", "--trusted-host", "--cert", "--client-cert", "--cache-dir"),
    "--root-user-action",
}


def pip_installs(command: str) -> list[tuple[list[str], list[str]]]:
    """(positional arguments, editable targets) of every ``pip install`` in a shell command line."""
    lexer = shlex.shlex(command, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    tokens = list(lexer)
    installs = []
    for i in range(len(tokens) - 1):
        if not (re.fullmatch(r"pip[0-9.]*", posixpath.basename(tokens[i])) and tokens[i + 1] == "install"):
            continue
        positional, editable, j = [], [], i + 2
        while j < len(tokens) and not re.fullmatch(r"[();<>|&]+", tokens[j]):
            token = tokens[j]
            if token in ("-e", "--editable") and j + 1 < len(tokens):
                editable.append(tokens[j + 1])
            if token.startswith("--editable=") or (token.startswith("-e") and len(token) > 2):
                editable.append(token)
            if token in PIP_VALUE_OPTIONS:
                j += 1
            elif not token.startswith("-"):
                positional.append(token)
            j += 1
        installs.append((positional, editable))
    return installs


def local_path(requirement: str) -> str | None:
    """The folder a ``pip install`` argument names (``.``, ``/src``, ``.[extra]``), or None for a requirement."""
    if "://" in requirement or not requirement.startswith((".", "/")):
        return None
    return re.sub(r"\[[^\]]*\]$", "", requirement)


@dataclass
class Replay:
    """What replaying the Dockerfile produced: ``root`` stands for the image's ``/``."""

    root: Path
    installs: list[Path] = field(default_factory=list)
    """Snapshots of the trees the Dockerfile's ``pip install`` names, as they were when it ran."""
    copied: list[str] = field(default_factory=list)
    """Every image path a COPY/ADD wrote."""
    entrypoint: list[str] = field(default_factory=list)
    cmd: list[str] = field(default_factory=list)

    def at(self, image_path: str) -> Path:
        return self.root / image_path.lstrip("/")


def replay(dockerfile: str, context: Context, root: Path, snapshots: Path) -> Replay:
    """Copy what the Dockerfile's COPY/ADD name from ``context`` into ``root``, as the image would hold it."""
    result, workdir = Replay(root), "/"
    root.mkdir(parents=True)
    steps = instructions(dockerfile)
    stages = [step for step in steps if step.keyword == "FROM"]
    assert len(stages) == 1, "the replay reads single-stage Dockerfiles only: extend it for a multi-stage build"
    for step in steps:
        where = f"Dockerfile line {step.line}: {step.keyword} {step.args}"
        if step.keyword == "WORKDIR":
            assert "$" not in step.args, f"{where}: variables are not replayed"
            workdir = posixpath.normpath(posixpath.join(workdir, step.args))
        elif step.keyword in ("COPY", "ADD"):
            assert "$" not in step.args, f"{where}: variables are not replayed"
            args = step.args
            while flag := re.match(r"--([\w-]+)(=\S*)?\s+", args):
                assert flag[1] in ("chown", "chmod", "link"), f"{where}: --{flag[1]} is not replayed"
                args = args[flag.end() :]
            *sources, dest = exec_form(args) or args.split()
            assert sources, f"{where}: nothing to copy"
            named = []
            for source in sources:
                assert "://" not in source and not source.startswith("git@"), f"{where}: remote sources"
                assert step.keyword == "COPY" or not re.search(r"\.(tar|tgz|tbz2?|txz)(\.\w+)?$", source), (
                    f"{where}: ADD unpacks archives, which the replay does not"
                )
                found = context.sources(source)
                assert found, f"{where}: {source!r} is not in the build context (missing, or left out by .dockerignore)"
                named += found
            target = posixpath.normpath(posixpath.join(workdir, dest))
            into_dir = dest.endswith("/") or posixpath.basename(dest) == "." or len(named) > 1
            into_dir = into_dir or result.at(target).is_dir()
            for source in named:
                if source in context.dirs or source == ".":  # a folder: its contents, not the folder itself
                    prefix = "" if source == "." else source + "/"
                    pairs = [(f, posixpath.join(target, f[len(prefix) :])) for f in context.files_under(source)]
                    result.at(target).mkdir(parents=True, exist_ok=True)
                else:
                    pairs = [(source, posixpath.join(target, posixpath.basename(source)) if into_dir else target)]
                for src, dst in pairs:
                    result.at(dst).parent.mkdir(parents=True, exist_ok=True)
                    if result.at(dst).is_symlink() or result.at(dst).is_file():
                        result.at(dst).unlink()
                    shutil.copy2(context.root / src, result.at(dst), follow_symlinks=False)
                    result.copied.append(dst)
        elif step.keyword == "RUN":
            argv = exec_form(step.args)
            if argv is None:
                command = step.args
            elif len(argv) == 3 and argv[1] == "-c" and posixpath.basename(argv[0]) in ("sh", "bash"):
                command = argv[2]
            else:
                command = shlex.join(argv)
            for positional, editable in pip_installs(command):
                assert not editable, f"{where}: the image must hold a regular install, not an editable one"
                for requirement in positional:
                    path = local_path(requirement)
                    if path is None:
                        continue
                    tree = result.at(posixpath.normpath(posixpath.join(workdir, path)))
                    assert (tree / "pyproject.toml").is_file() or (tree / "setup.py").is_file(), (
                        f"{where}: {requirement} (in {workdir}) is no project folder in the replayed image"
                    )
                    snapshot = snapshots / f"install-{len(result.installs)}"
                    shutil.copytree(tree, snapshot, symlinks=True)
                    result.installs.append(snapshot)
        elif step.keyword in ("ENTRYPOINT", "CMD"):
            argv = exec_form(step.args)
            assert argv is not None, f"{where}: a shell-form {step.keyword} runs /bin/sh, not the command itself"
            if step.keyword == "ENTRYPOINT":
                result.entrypoint = argv
            else:
                result.cmd = argv
    return result


# ---------------------------------------------------------------------------------------------------------------
# pyproject.toml and compose.yaml


@functools.cache
def pyproject_packages() -> dict[str, list[str]]:
    """Package -> its module files, for every package of pyproject's find configuration that holds modules."""
    from setuptools import find_namespace_packages, find_packages

    packages = tomllib.loads(PYPROJECT.read_text())["tool"]["setuptools"]["packages"]
    assert isinstance(packages, dict) and "find" in packages, "pyproject.toml lists no packages.find"
    find = packages["find"]
    assert find.get("where", ["."]) == ["."], "the check maps package names to folders of the repository root"
    finder = find_namespace_packages if find.get("namespaces", True) else find_packages
    found = finder(where=str(REPO), include=find.get("include", ["*"]), exclude=find.get("exclude", []))
    modules = {name: sorted(p.name for p in (REPO / name.replace(".", "/")).glob("*.py")) for name in found}
    return {name: files for name, files in modules.items() if files and "__pycache__" not in name.split(".")}


def words(value: str | list[Any]) -> list[str]:
    """A compose command or entrypoint as an argument list (a string is split as a shell would, without one)."""
    return shlex.split(value) if isinstance(value, str) else [str(v) for v in value]


def image_commands(image: Replay) -> dict[str, list[str]]:
    """The argument list each container of this image starts with: compose's services built from the Dockerfile,
    and ``docker run`` of the image with its defaults."""
    spec: dict[str, Any] = yaml.safe_load(COMPOSE.read_text())
    commands = {"image default (ENTRYPOINT + CMD)": image.entrypoint + image.cmd}
    for name, service in spec["services"].items():
        build = service.get("build")
        if build is None:
            continue  # another image (the eclipse/zenoh router)
        context = build if isinstance(build, str) else build.get("context", ".")
        dockerfile = "Dockerfile" if isinstance(build, str) else build.get("dockerfile", "Dockerfile")
        assert (COMPOSE.parent / context / dockerfile).resolve() == DOCKERFILE, f"{name} builds another Dockerfile"
        entrypoint = words(service["entrypoint"]) if "entrypoint" in service else image.entrypoint
        # compose's entrypoint drops the image's CMD too
        default = [] if "entrypoint" in service else image.cmd
        commands[f"compose service {name}"] = entrypoint + (
            words(service["command"]) if "command" in service else default
        )
    assert len(commands) > 1, "no compose service is built from the Dockerfile"
    for name, argv in commands.items():
        assert argv, f"{name} starts nothing"
    return commands


# ---------------------------------------------------------------------------------------------------------------
# The fresh environment


def dependency_view(dest: Path, project: set[str]) -> None:
    """Links to every entry of the running (dev) environment's site-packages except the project's own: its
    packages, its dist-info and its editable-install hook."""
    dest.mkdir()
    paths = sysconfig.get_paths()
    for site_dir in dict.fromkeys([paths["purelib"], paths["platlib"]]):
        for entry in Path(site_dir).iterdir():
            name = entry.name
            stem = name.split("-")[0].split(".")[0]
            if name.startswith("__editable__") or stem in project or stem.lower() == DIST_NAME:
                continue
            if name.endswith((".pth", ".egg-link")) and str(REPO) in entry.read_text(errors="replace"):
                continue
            if not (dest / name).exists():
                (dest / name).symlink_to(entry)


def clean_env(bin_dir: Path, home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PIP_", "VIRTUAL_ENV"))}
    dev_prefix = Path(sys.prefix).resolve()
    path = [
        p
        for p in env.get("PATH", "/usr/bin:/bin").split(os.pathsep)
        if not Path(p).resolve().is_relative_to(dev_prefix)
    ]
    env["PATH"] = os.pathsep.join([str(bin_dir), *path])
    env["MPLCONFIGDIR"] = str(home / "matplotlib")
    return env


@dataclass
class Image:
    replay: Replay
    python: Path
    bin: Path
    site: Path
    """The fresh environment's site-packages: where the image's packages must come from."""
    outside: Path
    """An empty folder outside the repository and the replayed tree: the working directory of every command."""
    env: dict[str, str]

    def run(self, argv: list[str], timeout: float = 180) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            argv, cwd=self.outside, env=self.env, capture_output=True, text=True, timeout=timeout, check=False
        )


def tail(text: str, lines: int = 30) -> str:
    """The last ``lines`` lines of ``text``, importlib's frozen frames left out of tracebacks."""
    kept = [line for line in text.strip().splitlines() if not line.lstrip().startswith('File "<frozen')]
    return "\n".join(kept[-lines:])


@pytest.fixture(scope="module")
def image(tmp_path_factory: pytest.TempPathFactory) -> Image:
    tmp = tmp_path_factory.mktemp("image")
    assert not tmp.resolve().is_relative_to(REPO), "the replay must happen outside the repository"
    context = Context.of(REPO, DOCKERIGNORE.read_text() if DOCKERIGNORE.exists() else "")
    snapshots = tmp / "snapshots"
    snapshots.mkdir()
    replayed = replay(DOCKERFILE.read_text(), context, tmp / "root", snapshots)
    assert replayed.installs, "the Dockerfile pip-installs no folder it copied: the image would hold no project"

    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=False, symlinks=True).create(env_dir)
    python = env_dir / "bin" / "python"
    outside = tmp / "cwd"
    outside.mkdir()
    paths = subprocess.run(
        [python, "-I", "-c", "import json, sysconfig; print(json.dumps(sysconfig.get_paths()))"],
        cwd=outside,
        capture_output=True,
        text=True,
        check=True,
    )
    site_dir = Path(json.loads(paths.stdout)["purelib"])
    project = {name.split(".")[0] for name in pyproject_packages()}
    dependency_view(tmp / "dependencies", project)
    (site_dir / "_dev_dependencies.pth").write_text(f"import site; site.addsitedir({str(tmp / 'dependencies')!r})\n")

    fresh = Image(replayed, python, env_dir / "bin", site_dir, outside, clean_env(env_dir / "bin", tmp))
    for tree in replayed.installs:
        pip = [str(python), "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "--no-cache-dir"]
        done = fresh.run([*pip, "--disable-pip-version-check", "--no-input", str(tree)], timeout=300)
        assert done.returncode == 0, (
            f"pip install of the replayed {tree.name} failed:\n{tail(done.stdout + done.stderr)}"
        )
    return fresh


# ---------------------------------------------------------------------------------------------------------------
# The replay itself, on a made-up context


def test_replay_follows_docker_copy_and_dockerignore_rules(tmp_path: Path) -> None:
    ctx = tmp_path / "ctx"
    made = ("pkg/__init__.py", "pkg/__pycache__/x.pyc", "pkg/sub/mod.py", "README.md", "pyproject.toml", "a.egg-info/I")
    for path in made:
        (ctx / path).parent.mkdir(parents=True, exist_ok=True)
        (ctx / path).write_text(path)
    (ctx / "docs").mkdir()
    (ctx / "docs" / "keep.md").write_text("kept")
    (ctx / "docs" / "drop.md").write_text("dropped")
    ignore = "# comment\n**/__pycache__\n*.egg-info\n/docs\n!docs/keep.md\n"
    context = Context.of(ctx, ignore)
    assert context.files == {"pkg/__init__.py", "pkg/sub/mod.py", "README.md", "pyproject.toml", "docs/keep.md"}

    dockerfile = (
        "# syntax=docker/dockerfile:1\nFROM python:3.11-slim\nWORKDIR /src\n"
        'COPY README.md pyproject.toml ./\nCOPY pkg lib/pkg\nCOPY --chown=1000 ["docs", "/d/"]\n'
        "COPY . /all\nRUN pip install --no-cache-dir torch==1 \\\n   && pip install -r r.txt .\n"
        'ENTRYPOINT ["tool"]\nCMD ["--help"]\n'
    )
    done = replay(dockerfile, context, tmp_path / "root", tmp_path)
    assert (done.root / "src/README.md").is_file()
    assert (done.root / "src/lib/pkg/sub/mod.py").is_file() and not (done.root / "src/lib/pkg/pkg").exists()
    assert (done.root / "d/keep.md").is_file() and not (done.root / "d/drop.md").exists()
    assert (done.root / "all/pkg/__init__.py").is_file() and not (done.root / "all/pkg/__pycache__").exists()
    assert done.entrypoint == ["tool"] and done.cmd == ["--help"]
    assert pip_installs("pip install --no-cache-dir torch==1 --index-url https://x && pip3 install . > log") == [
        (["torch==1"], []),
        (["."], []),
    ]
    assert [p.name for p in done.installs] == ["install-0"] and (done.installs[0] / "lib/pkg/sub/mod.py").is_file()
    with pytest.raises(AssertionError, match="no project folder"):
        replay("FROM x\nWORKDIR /src\nCOPY pkg pkg\nRUN pip install .\n", context, tmp_path / "root2", tmp_path)
    with pytest.raises(AssertionError, match="not in the build context"):
        replay("FROM x\nCOPY docs/drop.md /\n", context, tmp_path / "root3", tmp_path)
    with pytest.raises(AssertionError, match="editable"):
        replay("FROM x\nRUN pip install -e .\n", context, tmp_path / "root4", tmp_path)


# ---------------------------------------------------------------------------------------------------------------
# The replayed image


@pytest.mark.slow
def test_image_installs_every_package_pyproject_selects(image: Image) -> None:
    missing = {
        package: [m for m in modules if not (image.site / package.replace(".", "/") / m).is_file()]
        for package, modules in pyproject_packages().items()
    }
    missing = {package: modules for package, modules in missing.items() if modules}
    assert not missing, (
        "packages (modules) that pyproject.toml's [tool.setuptools.packages.find] selects from the repository but "
        f"the image does not install (is the Dockerfile copying all of them?): {missing}"
    )


@pytest.mark.slow
def test_image_has_the_console_script(image: Image) -> None:
    script = image.bin / "ennc-ql"
    assert script.is_file() and os.access(script, os.X_OK), "pip installed no ennc-ql console script"
    assert Path(script.read_text().splitlines()[0][2:]).parent == image.bin, "ennc-ql runs another interpreter"
    records = list(image.site.glob(f"{DIST_NAME}-*.dist-info/entry_points.txt"))
    assert len(records) == 1, f"the image holds {len(records)} installs of the project"
    for name, target in tomllib.loads(PYPROJECT.read_text())["project"]["scripts"].items():
        assert f"{name} = {target}" in records[0].read_text(), f"the console script {name} is not installed"
        assert os.access(image.bin / name, os.X_OK), f"no {name} in the environment's bin"


@pytest.mark.slow
def test_every_image_command_starts(image: Image, tmp_path: Path) -> None:
    """Each command with ``--help``, all at once (each spends seconds importing torch, numba and rerun)."""
    failures, started = [], []
    for i, (name, argv) in enumerate(image_commands(image.replay).items()):
        program = shutil.which(posixpath.basename(argv[0]), path=str(image.bin))
        if program is None:
            failures.append(f"{name}: {argv[0]} is not installed in the image")
            continue
        out, err = tmp_path / f"{i}.out", tmp_path / f"{i}.err"
        with out.open("w") as stdout, err.open("w") as stderr:
            proc = subprocess.Popen(
                [program, *argv[1:], "--help"], cwd=image.outside, env=image.env, stdout=stdout, stderr=stderr
            )
        started.append((name, [*argv, "--help"], proc, out, err))
    for name, argv, proc, out, err in started:
        try:
            code = proc.wait(timeout=180)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait()
        if code != 0 or "usage:" not in out.read_text():
            failures.append(f"{name}: `{shlex.join(argv)}` exited {code}:\n{tail(err.read_text())}")
    assert not failures, "\n\n".join(failures)


PROBE = r"""
import importlib, importlib.metadata, json, pkgutil, sys, traceback

commands, tops = json.loads(sys.argv[1]), json.loads(sys.argv[2])


def project_modules():
    files = {}
    for name, module in list(sys.modules.items()):
        if name.partition(".")[0] in tops:
            origin = getattr(getattr(module, "__spec__", None), "origin", None)
            files[name] = list(getattr(module, "__path__", [])) if origin in (None, "namespace") else [origin]
    return files


scripts = {ep.name: ep for ep in importlib.metadata.entry_points(group="console_scripts")}
result = {"commands": {}}
for name, argv in commands.items():
    entry = {"modules": [], "error": None}
    try:
        point = scripts[argv[0].rpartition("/")[2]]
        module = importlib.import_module(point.module)
        entry["modules"].append(point.module)
        build_parser = getattr(module, "build_parser", None)
        args = [a for a in argv[1:] if a not in ("-h", "--help")]
        if build_parser is not None and args:
            parser = build_parser()
            try:
                parsed = parser.parse_args(args)
            except SystemExit:
                raise RuntimeError(f"{parser.prog} does not take {args}") from None
            func = getattr(parsed, "func", None)
            if func is not None:
                entry["modules"].append(importlib.import_module(func.__module__).__name__)
    except BaseException:
        entry["error"] = traceback.format_exc()
    entry["loaded"] = project_modules()
    result["commands"][name] = entry

errors = {}
for top in tops:
    try:
        package = importlib.import_module(top)
    except BaseException:
        errors[top] = traceback.format_exc()
        continue
    onerror = lambda name: errors.setdefault(name, traceback.format_exc())
    for info in pkgutil.walk_packages(package.__path__, top + ".", onerror=onerror):
        try:
            importlib.import_module(info.name)
        except BaseException:
            errors[info.name] = traceback.format_exc()
result["all"] = {"loaded": project_modules(), "errors": errors}
print(json.dumps(result))
"""


@pytest.mark.slow
def test_image_commands_import_their_modules_from_the_image(image: Image) -> None:
    commands = image_commands(image.replay)
    tops = sorted({name.split(".")[0] for name in pyproject_packages()})
    done = image.run([str(image.python), "-I", "-c", PROBE, json.dumps(commands), json.dumps(tops)], timeout=300)
    assert done.returncode == 0, f"the import probe failed:\n{tail(done.stderr)}"
    result = json.loads(done.stdout.strip().splitlines()[-1])
    site_dir = image.site.resolve()

    failures = []
    for name, entry in [*result["commands"].items(), ("every module of the project's packages", result["all"])]:
        if entry.get("error"):
            failures.append(f"{name}: importing its modules failed:\n{tail(entry['error'], 8)}")
        for module, error in entry.get("errors", {}).items():
            failures.append(f"{name}: import of {module} failed:\n{tail(error, 3)}")
        for module, files in sorted(entry["loaded"].items()):
            outside = [f for f in files if not Path(f).resolve().is_relative_to(site_dir)]
            if outside or not files:
                failures.append(f"{name}: {module} comes from {outside or files}, not the image's site-packages")
    assert not failures, "\n\n".join(failures)
    for name, entry in result["commands"].items():
        assert len(entry["modules"]) >= 1, f"{name}: no module of the command was imported"


# ---------------------------------------------------------------------------------------------------------------
# The real build (scripts/image_check.py, `make image-test`): what the suite can check without building


def arg_defaults(dockerfile: str) -> dict[str, str]:
    """Each ``ARG NAME=default`` of the Dockerfile, its quotes removed as the builder does."""
    defaults = {}
    for step in instructions(dockerfile):
        if step.keyword == "ARG" and "=" in step.args:
            name, value = step.args.split("=", 1)
            defaults[name] = shlex.split(value)[0]
    return defaults


def test_the_dockerfile_builds_for_real_users_by_default() -> None:
    """The build arguments that let the real build run here default to what a user with a registry needs: the
    official Python image, and torch from PyTorch's CPU-only index at pyproject's pin."""
    text = DOCKERFILE.read_text()
    defaults = arg_defaults(text)
    assert defaults["BASE"] == "python:3.11-slim"
    assert [s.args for s in instructions(text) if s.keyword == "FROM"] == ["${BASE}"]
    assert defaults["TORCH_SOURCE"] == "--index-url https://download.pytorch.org/whl/cpu"
    pin = next(d for d in tomllib.loads(PYPROJECT.read_text())["project"]["dependencies"] if d.startswith("torch"))
    torch_runs = [s.args for s in instructions(text) if s.keyword == "RUN" and "torch" in s.args]
    assert torch_runs == [f"pip install --no-cache-dir {pin} ${{TORCH_SOURCE}}"]


def image_check() -> Any:
    """scripts/image_check.py as a module (scripts/ is no package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("image_check", REPO / "scripts" / "image_check.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_the_real_build_runs_compose_s_services_as_compose_does(tmp_path: Path) -> None:
    """The containers of `make image-test` start with compose's own commands (budgets appended, later flags win),
    mount what compose mounts, and the plain router is ``ennc-ql router`` with the eclipse/zenoh router's flags."""
    from ennc_ql.cli import build_parser

    check = image_check()
    plain = yaml.safe_load(COMPOSE.read_text())
    services = {s.name: s for s in check.plain_services(plain)}
    replicas = plain["services"]["actor"]["deploy"]["replicas"]
    assert list(services) == ["router", "learner", *(f"actor-{i}" for i in range(replicas))]
    router = build_parser().parse_args(services["router"].command)
    assert router.command == "router" and router.listen == ["tcp/0.0.0.0:7447"] and not router.multicast_scouting
    assert (
        services["learner"].command[: len(plain["services"]["learner"]["command"])]
        == plain["services"]["learner"]["command"]
    )
    assert services["learner"].volumes == {"runs": "/runs"}
    assert (
        services["actor-0"].command[: len(plain["services"]["actor"]["command"])]
        == plain["services"]["actor"]["command"]
    )
    secure_spec = yaml.safe_load((REPO / "compose.secure.yaml").read_text())
    secure = {s.name: s for s in check.secure_services(secure_spec, tmp_path)}
    assert list(secure) == list(secure_spec["services"])
    for name, service in secure_spec["services"].items():
        assert secure[name].command[: len(service["command"])] == service["command"]
        mounted = {
            f"/run/secrets/{s['target']}": Path(secure_spec["secrets"][s["source"]]["file"]).name
            for s in service["secrets"]
        }
        assert {target: Path(source).name for source, target in secure[name].files.items()} == mounted
        assert all(Path(source).parent == tmp_path for source in secure[name].files)
