# cogmap web app: `cogmap serve` on port 8080 with the built-in rat-maze dataset baked in, run by
# an unprivileged user. Publish the port on this machine's loopback only:
#
#   docker build -t cogmap .
#   docker run --rm -p 127.0.0.1:8080:8080 cogmap
#
# then open the URL the log prints (`docker logs`), http://<container>:8080/?token=..., as
# http://localhost:8080/?token=... . Inside the container the server listens on every interface
# (the published port arrives there), so it asks for that token; `-e COGMAP_TOKEN=<at least 16
# characters>` fixes it. Bags to open from the page: `-v "$PWD/bags:/data:ro"`; replays the page
# saves go to /exports (`-v "$PWD/exports:/exports"`, a folder user 10001 may write).
# Sharing with colleagues: docs/security.md.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    COGMAP_CACHE=/var/cache/cogmap \
    NUMBA_CACHE_DIR=/var/cache/cogmap/numba

RUN apt-get update \
    && apt-get install -y --no-install-recommends libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

# The user owns only the cache (the built-in dataset, event files) and the export folder; the
# code and the Python installation stay root's, read-only to it.
RUN groupadd --system --gid 10001 cogmap \
    && useradd --system --uid 10001 --gid cogmap --create-home --home-dir /home/cogmap \
        --shell /usr/sbin/nologin cogmap \
    && mkdir -p /var/cache/cogmap /data /exports \
    && chown cogmap:cogmap /var/cache/cogmap /exports

WORKDIR /opt/cogmap
COPY pyproject.toml README.md ./
COPY cogmap_core ./cogmap_core
COPY app ./app
COPY static ./static
RUN pip install .

USER cogmap:cogmap

# Generate the default dataset into $COGMAP_CACHE at build time: the container starts at once.
RUN cogmap dataset path
# Compile the map replay, its path search and the front end's loops (numba:
# cogmap_core/compiled_replay.py, compiled_search.py, frontend/compiled.py) into that cache as
# that user too: neither the first parameter change nor the first frame waits for them (the
# installed code itself is read-only).
RUN python -c "from cogmap_core import compiled_replay as c; assert c.available(), c.unavailable_reason()" \
 && python -c "from cogmap_core.frontend.compiled import kernels; assert kernels() is not None"

EXPOSE 8080
# `cogmap serve` stops cleanly on SIGTERM (docker stop) as on Ctrl-C. The page lists the bags of
# the cache and of /data, and saves replays in /exports only.
CMD ["cogmap", "serve", "--host", "0.0.0.0", "--port", "8080", \
     "--data-dir", "/var/cache/cogmap", "--data-dir", "/data", "--export-dir", "/exports"]
