"""The S3 file store against a real S3-compatible server (moto's, over HTTP): the same interface as the
folder store (put once, read back, a missing file is FileNotFoundError), its objects under the prefix
with their media type, and a wrong bucket stops the service's start with the reason."""

from __future__ import annotations

import hashlib

import pytest
from sqlmodel import Session

from app.cli import main as setupcam
from app.config import Settings
from app.store.db import make_engine, migrate
from app.store.files import FileStoreError, FolderStore, S3Store, open_file_store
from app.store.models import StoredFile
from tests.support.s3 import s3_server


@pytest.fixture(scope="module")
def s3():
    with s3_server() as server:
        yield server


@pytest.fixture()
def engine(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'db.sqlite'}")
    migrate(engine)
    yield engine
    engine.dispose()


def test_s3_store_puts_once_under_its_prefix_and_reads_back(s3, engine, tmp_path):
    bucket = s3.new_bucket()
    store = open_file_store(Settings(SETUPCAM_DATA_DIR=str(tmp_path / "data"), **s3.settings(bucket, "cell-2/")))
    assert isinstance(store, S3Store) and store.describe() == f"s3://{bucket}/cell-2 at {s3.endpoint_url}"
    data = b"\x89PNG a stage picture"
    sha = hashlib.sha256(data).hexdigest()
    assert not store.exists(sha)
    with Session(engine) as session:
        assert store.put(session, data, "image/png") == sha
        assert store.put(session, data, "image/png") == sha  # the same bytes: nothing new
        session.commit()
        assert session.get(StoredFile, sha).size_bytes == len(data)
        assert store.media_type(session, sha) == "image/png"
    assert s3.keys(bucket) == [f"cell-2/{sha[:2]}/{sha}"]
    head = s3.client().head_object(Bucket=bucket, Key=f"cell-2/{sha[:2]}/{sha}")
    assert head["ContentType"] == "image/png" and head["ContentLength"] == len(data)
    assert store.exists(sha) and store.read(sha) == data
    assert not (tmp_path / "data" / "files").exists(), "nothing goes to the local folder"
    # a second store on the same bucket (another worker machine) reads what the first wrote
    other = S3Store(bucket, "cell-2", endpoint_url=s3.endpoint_url, region="us-east-1",
                    access_key_id="setupcam-test", secret_access_key="setupcam-test-secret")
    assert other.read(sha) == data
    missing = hashlib.sha256(b"never stored").hexdigest()
    with pytest.raises(FileNotFoundError, match=missing):
        store.read(missing)
    # another prefix is another store: it does not see the first one's files
    assert not S3Store(bucket, "cell-3", client=store.client).exists(sha)


def test_the_factory_picks_the_store_and_refuses_a_wrong_bucket(s3, tmp_path, monkeypatch, capsys):
    data = tmp_path / "data"
    assert isinstance(open_file_store(Settings(SETUPCAM_DATA_DIR=str(data))), FolderStore)
    assert open_file_store(Settings(SETUPCAM_DATA_DIR=str(data))).root == data.resolve() / "files"
    shared = open_file_store(Settings(SETUPCAM_DATA_DIR=str(data), SETUPCAM_FILE_STORE=str(tmp_path / "share")))
    assert isinstance(shared, FolderStore) and shared.root == (tmp_path / "share").resolve()
    with pytest.raises(FileStoreError, match="name a bucket"):
        open_file_store(Settings(SETUPCAM_DATA_DIR=str(data), SETUPCAM_FILE_STORE="s3:///prefix"))
    with pytest.raises(FileStoreError, match="no such bucket"):
        open_file_store(Settings(SETUPCAM_DATA_DIR=str(data), **s3.settings("setupcam-no-such-bucket", "x")))
    # `setupcam serve` says so in one sentence and does not start
    monkeypatch.setenv("SETUPCAM_DATA_DIR", str(data))  # restored afterwards (serve --data-dir sets it)
    for name, value in s3.env("setupcam-no-such-bucket", "x").items():
        monkeypatch.setenv(name, value)
    monkeypatch.setenv("SETUPCAM_LOAD_EXAMPLES", "false")
    assert setupcam(["serve", "--data-dir", str(data), "--port", "1"]) == 1
    err = capsys.readouterr().err
    assert "setupcam serve: file store: s3://setupcam-no-such-bucket/x" in err and "no such bucket" in err, err
    assert "setupcam-test-secret" not in err
