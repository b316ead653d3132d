"""softplc runtime: language, compiler, engine, plant, scheduler, console, CLI."""
