/*
 *  neuvisionmodule.cpp
 *
 *  The NEST extension module of NeuVision: registers izhikevich_neuvision.
 *  Built by sim_network/nest_module.py, loaded with nest.Install(<path>).
 *
 *  Part of NeuVision (GPL-3.0-or-later), built against NEST (GPL-2.0-or-later).
 */

#include "nest_extension_interface.h"

#include "izhikevich_neuvision.h"

class neuvisionmodule : public nest::NESTExtensionInterface
{
public:
  void
  initialize() override
  {
    neuvision::register_izhikevich_neuvision( "izhikevich_neuvision" );
  }
};

// The symbol NEST's module loader looks for: <module name>_LTX_module.
neuvisionmodule neuvisionmodule_LTX_module;
