"""requirements.lock pins every requirement with hashes, made from this requirements.txt."""
from ft_cli.commands import lock


def test_the_lock_matches_the_requirements():
    assert lock.lock_problems() == []


def test_the_check_fails_on_an_unpinned_requirement_or_another_requirements_file(tmp_path):
    req = tmp_path / 'requirements.txt'
    req.write_text(lock.REQUIREMENTS.read_text() + 'a-package-nobody-pinned>=1\n')
    problems = lock.lock_problems(req, lock.LOCK)
    assert any('not made from this requirements.txt' in p for p in problems), problems
    assert any('a-package-nobody-pinned' in p for p in problems), problems


def test_the_check_fails_on_a_pin_without_hashes(tmp_path):
    text = lock.LOCK.read_text()
    bad = tmp_path / 'requirements.lock'
    bad.write_text(text + 'extra-thing==1.0\n')
    assert any('without hashes' in p for p in lock.lock_problems(lock.REQUIREMENTS, bad))


def test_requirement_names_are_normalised():
    text = '# c\n-r other.txt\nros-jazzy-rclpy\nnpTDMS>=1.0  # TDMS\nPyYAML ; python_version>"3"\n'
    assert lock.requirement_names(text) == ['ros-jazzy-rclpy', 'nptdms', 'pyyaml']
