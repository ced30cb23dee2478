"""./ft's subcommands, run inside the workspace environment that ./ft sets up.

    ft_cli/main.py          the parser: one subcommand per module of commands/
    ft_cli/paths.py         where the workspace and its built nodes are
    ft_cli/graph.py         starting node processes and collecting what they publish
    ft_cli/commands/
        demo.py             ./ft demo       the live graph on the five test sets
        thesis.py           ./ft thesis     the thesis's predictions and Tables 7-9 beside ours
        discover.py         ./ft discover   what the simulation gets wrong (force_discovery)
        bag.py              ./ft bag        bag and DAQ tools (bag_tools + force_correction)
        workspace.py        ./ft test, run, env, bench

The network lab (namespaces, links, the graph across two hosts) is tools/netlab.
"""
