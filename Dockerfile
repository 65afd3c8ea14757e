# The ennc-ql image: learner and actor processes (compose.yaml builds it; the router runs on eclipse/zenoh).
#
#   docker build -t ennc-ql .
#   docker run --rm ennc-ql actor --mode client --connect tcp/<router host>:7447 --id auto
FROM python:3.11-slim

WORKDIR /src

# torch first, from PyTorch's CPU-only index: the Linux wheel PyPI resolves for torch==2.13.0 is the CUDA build
# (several GB of GPU libraries a CPU container never loads). `pip install .` below then finds the pin of
# pyproject.toml already satisfied and keeps this one. For GPU hosts, use the CUDA index of pytorch.org instead.
RUN pip install --no-cache-dir torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu

COPY pyproject.toml README.md ./
COPY sim sim
COPY learner learner
COPY actors actors
COPY protocol protocol
COPY ennc_ql ennc_ql
RUN pip install --no-cache-dir .

# Not root: /runs is created here so that a named volume mounted on it starts out owned by this user.
RUN useradd --create-home --uid 1000 enncql && mkdir /runs && chown enncql /runs
USER enncql
WORKDIR /runs

# A learner listening for peers directly (without a router) uses zenoh's registered port.
EXPOSE 7447/tcp
ENTRYPOINT ["ennc-ql"]
CMD ["--help"]
