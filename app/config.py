"""One settings object, read from the environment (and an optional ``.env``).

Two services with different ``SETUPCAM_DATA_DIR`` / ``DATABASE_URL`` / ports run side by side.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.resources import bundled_dir


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_file=".env", extra="ignore", populate_by_name=True)

    data_dir: Path = Field(default=Path("var"), validation_alias="SETUPCAM_DATA_DIR",
                           description="Folder for the SQLite file, uploads, meshes and job images.")
    database_url: str = Field(default="", validation_alias="DATABASE_URL",
                              description="SQLAlchemy URL; empty means SQLite under data_dir.")
    viser_port: int = Field(default=8081, validation_alias="SETUPCAM_VISER_PORT")
    file_store: str = Field(default="", validation_alias="SETUPCAM_FILE_STORE",
                            description="Where images, meshes and pictures are kept (docs/jobs.md): empty = "
                                        "$SETUPCAM_DATA_DIR/files; a folder (a share every worker mounts); or "
                                        "s3://bucket/prefix, a bucket on an S3-compatible server.")
    s3_endpoint_url: str = Field(default="", validation_alias="SETUPCAM_S3_ENDPOINT_URL",
                                 description="The S3-compatible server, e.g. http://minio.plant:9000; empty = AWS.")
    s3_region: str = Field(default="", validation_alias="SETUPCAM_S3_REGION",
                           description="The bucket's region; empty = boto3's default (AWS_DEFAULT_REGION ...).")
    s3_access_key_id: str = Field(default="", validation_alias="SETUPCAM_S3_ACCESS_KEY_ID",
                                  description="Empty = boto3's own chain (AWS_ACCESS_KEY_ID, ~/.aws, instance role).")
    s3_secret_access_key: SecretStr | None = Field(default=None, validation_alias="SETUPCAM_S3_SECRET_ACCESS_KEY")
    models_library_dir: Path = Field(
        default_factory=lambda: bundled_dir("models_library"),
        validation_alias="SETUPCAM_MODELS_LIBRARY",
        description="Example library loaded on first start (idempotent).",
    )
    load_example_library: bool = Field(default=True, validation_alias="SETUPCAM_LOAD_EXAMPLES")
    max_upload_mb: float = Field(default=64.0, validation_alias="SETUPCAM_MAX_UPLOAD_MB")
    max_mesh_faces: int = Field(default=2_000_000, validation_alias="SETUPCAM_MAX_MESH_FACES")
    max_image_pixels: int = Field(default=50_000_000, gt=0, validation_alias="SETUPCAM_MAX_IMAGE_PIXELS",
                                  description="Pixels (width x height, read from the header before decoding) an "
                                              "uploaded image may have; above: 413.")
    max_request_pixels: int = Field(default=250_000_000, gt=0, validation_alias="SETUPCAM_MAX_REQUEST_PIXELS",
                                    description="Pixels of all images of one request together (a calibration or "
                                                "rotary run decodes them all); above: 413 before decoding.")
    max_request_mb: float = Field(default=256.0, gt=0, validation_alias="SETUPCAM_MAX_REQUEST_MB",
                                  description="Whole body of an upload request (several images); above: 413 "
                                              "before the body is read.")
    max_json_kb: float = Field(default=1024.0, gt=0, validation_alias="SETUPCAM_MAX_JSON_KB",
                               description="Body of a JSON (or text) request; above: 413 before it is read.")
    max_json_depth: int = Field(default=32, gt=0, validation_alias="SETUPCAM_MAX_JSON_DEPTH",
                                description="Nesting of arrays/objects a JSON body may have; deeper: 422.")
    workers: int = Field(default=1, ge=1, validation_alias="SETUPCAM_WORKERS",
                         description="Jobs the service's embedded worker runs at once (threads).")
    search_threads: int = Field(default=0, ge=0, validation_alias="SETUPCAM_SEARCH_THREADS",
                                description="Threads of a setup job's plane search (its resting states at once); "
                                            "0 = the service's embedded worker shares this machine's cores among "
                                            "the jobs it runs at once (SETUPCAM_WORKERS), a `setupcam worker` "
                                            "process takes 1. The result does not depend on it.")
    embedded_worker: bool = Field(default=True, validation_alias="SETUPCAM_EMBEDDED_WORKER",
                                  description="Run jobs inside the service (the SQLite default). false: the service "
                                              "only enqueues and `setupcam worker` processes run the jobs.")
    job_timeout_s: float = Field(default=600.0, gt=0, validation_alias="SETUPCAM_JOB_TIMEOUT_S",
                                 description="A job running longer fails with this reason.")
    job_max_attempts: int = Field(default=3, ge=1, validation_alias="SETUPCAM_JOB_MAX_ATTEMPTS",
                                  description="Starts of a job whose worker died before it is failed.")
    job_heartbeat_s: float = Field(default=2.0, gt=0, validation_alias="SETUPCAM_JOB_HEARTBEAT_S",
                                   description="How often a running job and its worker say they are alive.")
    job_stall_s: float = Field(default=30.0, gt=0, validation_alias="SETUPCAM_JOB_STALL_S",
                               description="A running job (or worker) silent this long is taken as dead: its "
                                           "job is queued again for another worker.")
    max_tilt_deg: float = Field(default=0.2, validation_alias="SETUPCAM_MAX_TILT_DEG",
                                description="Residual tilt a 3-axis work offset may ignore; above it export is refused.")
    max_sigma_mm: float = Field(default=0.3, validation_alias="SETUPCAM_MAX_SIGMA_MM",
                                description="1-sigma position uncertainty (x, y, z) a result may have to pass.")
    max_sigma_deg: float = Field(default=0.05, validation_alias="SETUPCAM_MAX_SIGMA_DEG",
                                 description="1-sigma rotation uncertainty about z a result may have to pass.")
    export_watch_s: float = Field(default=30.0, gt=0, validation_alias="SETUPCAM_EXPORT_WATCH_S",
                                  description="How often exports open for over 60 s are settled by reading the "
                                              "controller back.")
    max_adjust_mm: float = Field(default=1.0, gt=0, validation_alias="SETUPCAM_MAX_ADJUST_MM",
                                 description="An operator's move of a fitted part beyond this (or beyond 3 sigma) "
                                             "fails the uncertainty check until the part is refined.")
    max_adjust_deg: float = Field(default=0.5, gt=0, validation_alias="SETUPCAM_MAX_ADJUST_DEG")
    max_offset_change_mm: float = Field(default=5.0, validation_alias="SETUPCAM_MAX_OFFSET_CHANGE_MM",
                                        description="Export needs an acknowledgement when X/Y/Z change more than this.")
    max_offset_change_deg: float = Field(default=2.0, validation_alias="SETUPCAM_MAX_OFFSET_CHANGE_DEG")
    webhooks: list[dict] = Field(default_factory=list, validation_alias="SETUPCAM_WEBHOOKS",
                                 description='JSON list of {"url": ..., "secret": ...}; events are POSTed, '
                                             'signed with HMAC-SHA256 in X-Setupcam-Signature.')
    mqtt_url: str = Field(default="", validation_alias="SETUPCAM_MQTT_URL",
                          description="e.g. mqtt://127.0.0.1:1883; events go to <topic prefix>/<event type>")
    mqtt_topic_prefix: str = Field(default="setupcam", validation_alias="SETUPCAM_MQTT_TOPIC_PREFIX")
    allowed_origins: list[str] = Field(default_factory=list, validation_alias="SETUPCAM_ALLOWED_ORIGINS",
                                       description='JSON list of extra origins (e.g. ["https://cell2.example"]) '
                                                   "whose pages may write with the session cookie; the service's "
                                                   "own Host always may.")
    login_free_failures: int = Field(default=5, ge=1, validation_alias="SETUPCAM_LOGIN_FREE_FAILURES",
                                     description="Failed sign-ins per name or address before each further attempt "
                                                 "waits (60 s, doubling per failure, at most 15 min).")
    cookie_secure: bool = Field(default=False, validation_alias="SETUPCAM_COOKIE_SECURE",
                                description="Mark the session cookie Secure (set it when served over HTTPS).")
    log_json: bool = Field(default=True, validation_alias="SETUPCAM_LOG_JSON")

    @model_validator(mode="after")
    def _defaults(self) -> "Settings":
        self.data_dir = self.data_dir.resolve()
        if not self.database_url:
            self.database_url = f"sqlite:///{self.data_dir / 'setupcam.db'}"
        return self

    @property
    def files_dir(self) -> Path:
        """The folder of the file store: SETUPCAM_FILE_STORE when it names a folder, else data_dir/files
        (unused when the store is an S3 bucket)."""
        where = self.file_store.strip()
        if where and not where.startswith("s3://"):
            return Path(where).expanduser().resolve()
        return self.data_dir / "files"


@lru_cache
def get_settings() -> Settings:
    return Settings()
