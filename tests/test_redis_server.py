"""The test-run Redis guarantee works without a system Redis."""

from tests.redis_server import LocalRedis, redis_answers


def test_local_redis_starts_answers_and_stops() -> None:
    server = LocalRedis.start()
    try:
        assert redis_answers(server.url)
    finally:
        server.stop()
    assert not redis_answers(server.url, timeout_s=0.2)


def test_nothing_answers_on_a_closed_port() -> None:
    assert not redis_answers("redis://127.0.0.1:1/0", timeout_s=0.2)
