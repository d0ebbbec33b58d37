# cogmap web app: `cogmap serve` on port 8080 with the built-in rat-maze dataset baked in.
#   docker build -t cogmap . && docker run --rm -p 8080:8080 cogmap   # then open localhost:8080
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    COGMAP_CACHE=/opt/cogmap-cache

RUN apt-get update \
    && apt-get install -y --no-install-recommends libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/cogmap
COPY pyproject.toml README.md ./
COPY cogmap_core ./cogmap_core
COPY app ./app
COPY static ./static
RUN pip install .

# Generate the default dataset into $COGMAP_CACHE at build time: the container starts at once.
RUN cogmap dataset path

EXPOSE 8080
# `cogmap serve` stops cleanly on SIGTERM (docker stop) as on Ctrl-C.
CMD ["cogmap", "serve", "--host", "0.0.0.0", "--port", "8080"]
