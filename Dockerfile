# cogmap web app: `cogmap serve` on port 8080 with the default rat-maze dataset baked in.
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

# Generate the built-in default dataset at build time so the container starts instantly.
RUN cogmap dataset regenerate

EXPOSE 8080
CMD ["cogmap", "serve", "--host", "0.0.0.0", "--port", "8080"]
