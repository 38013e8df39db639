from sqlmodel import Session

from app.services import access
from app.store.db import make_engine, migrate


def test_passwords_and_keys_are_stored_hashed(tmp_path):
    engine = make_engine(f"sqlite:///{tmp_path / 'a.db'}")
    migrate(engine)
    with Session(engine) as s:
        first = access.ensure_first_admin(s)
        assert first and access.ensure_first_admin(s) is None
        user, pw = access.create_user(s, "dora", "operator", "correct horse")
        assert "correct horse" not in user.password_hash and access.verify_password("correct horse", user.password_hash)
        assert not access.verify_password("wrong", user.password_hash)
        row, secret = access.create_api_key(s, "mes", "mes")
        assert secret not in row.key_hash and access.resolve_token(s, secret) == access.Principal("mes", "apikey", "mes")
        assert access.login(s, "dora", "nope") is None
        _, token, _ = access.login(s, "dora", "correct horse")
        assert access.resolve_token(s, token).role == "operator"
