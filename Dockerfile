# The ennc-ql image: learner and actor processes (compose.yaml builds it; the router runs on eclipse/zenoh).
#
#   docker build -t ennc-ql .
#   docker run --rm ennc-ql actor --mode client --connect tcp/<router host>:7447 --actor-id auto
#
# The image gets the whole build context and `pip install .` of it, so the packages it holds are exactly those
# pyproject.toml's [tool.setuptools.packages.find] selects: no list of package folders here to keep in step.
# .dockerignore keeps out what the image does not need (.venv, .git, runs/, tests/, caches). tests/e2e/test_image.py
# replays this file without Docker and runs compose.yaml's commands in the result; `make image-test`
# (scripts/image_check.py) builds it for real with podman and trains with its containers.
#
# Build arguments, for hosts that cannot reach the defaults (the defaults are right everywhere else):
#   BASE          the base image: any with Python >= 3.11 on PATH as python and pip, and useradd
#   TORCH_SOURCE  pip options saying where torch comes from, e.g. "--index-url <a mirror of PyTorch's CPU index>"
#                 or "--find-links <a folder or URL holding the wheel>"
ARG BASE=python:3.11-slim
FROM ${BASE}

# Not root: /runs is created here so that a named volume mounted on it starts out owned by this user.
RUN useradd --create-home --uid 1000 enncql && mkdir /runs && chown enncql /runs

WORKDIR /src

# torch first, from PyTorch's CPU-only index: the Linux wheel PyPI resolves for torch==2.13.0 is the CUDA build
# (several GB of GPU libraries a CPU container never loads). The installs below then find the pin of
# pyproject.toml already satisfied and keep this one. For GPU hosts, give the CUDA index of pytorch.org instead.
ARG TORCH_SOURCE="--index-url https://download.pytorch.org/whl/cpu"
RUN pip install --no-cache-dir torch==2.13.0 ${TORCH_SOURCE}

# The other runtime dependencies, read from pyproject.toml alone: this layer is rebuilt only when pyproject.toml
# changes, not on every change of the code.
COPY pyproject.toml ./
RUN python -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" \
        > /tmp/requirements.txt \
    && pip install --no-cache-dir -r /tmp/requirements.txt \
    && rm /tmp/requirements.txt

# The project itself, a regular (not editable) install: the processes run from site-packages, not from /src.
COPY . .
RUN pip install --no-cache-dir . && rm -rf build ./*.egg-info

USER enncql
WORKDIR /runs

# A learner listening for peers directly (without a router) uses zenoh's registered port.
EXPOSE 7447/tcp
ENTRYPOINT ["ennc-ql"]
CMD ["--help"]
