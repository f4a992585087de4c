"""`python -m oneshot` names the package's commands: each is a module, `python -m oneshot.COMMAND`, with
--help (`oneshot.demo` first). Without one, the one line and exit status 2 of any command line that
names no command (`python -m oneshot.benchmark`)."""
import sys

COMMANDS = ("demo", "collect", "train", "evaluate", "experiments", "exercises", "benchmark")


def main():
    sys.stderr.write(f"error: python -m oneshot runs nothing itself; name a command: python -m oneshot.demo (start "
                     f"here), or {', '.join(COMMANDS[1:-1])} or {COMMANDS[-1]} as python -m oneshot.COMMAND "
                     f"(each with --help)\n")
    return 2


if __name__ == "__main__":
    sys.exit(main())
