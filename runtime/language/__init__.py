"""Language: the syntax tree, the expression parser, the type checker, the model,
the YAML source with positions, and the loading of grafcet and plant files."""
