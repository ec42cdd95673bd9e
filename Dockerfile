# syntax=docker/dockerfile:1
# limbstream services image: emulate, aggregate, dashboard (and router/watch/eval) in one.
#   docker build -t limbstream .
#   docker run --rm limbstream emulate --help
# Stage 1 compiles the C kernel (firmware_c/) into the wheel and collects every dependency as a wheel;
# stage 2 installs them offline on a slim base and runs as an unprivileged user.

ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml setup.py README.md LICENSE ./
COPY firmware_c/include firmware_c/include
COPY firmware_c/src firmware_c/src
COPY firmware_c/host firmware_c/host
COPY firmware_c/vqf firmware_c/vqf
COPY limbstream limbstream
COPY device_emulator device_emulator
COPY services services
COPY dashboard dashboard
RUN pip wheel --no-cache-dir --wheel-dir /wheels .

FROM ${PYTHON_IMAGE} AS runtime
RUN useradd --create-home --uid 10001 --user-group limbstream
COPY --from=build /wheels /wheels
RUN pip install --no-cache-dir --no-index --find-links /wheels limbstream \
    && rm -rf /wheels
ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1
USER limbstream
WORKDIR /home/limbstream
EXPOSE 8000
ENTRYPOINT ["limbstream"]
CMD ["--help"]
