/*
 *  izhikevich_neuvision.h
 *
 *  NEST's izhikevich neuron (forward Euler at the resolution, spike inputs as voltage
 *  jumps in mV) with the two currents of NeuVision's default culture:
 *
 *  - a spike-frequency adaptation current w (mV/ms), subtracted from the input; it grows
 *    by adapt_increment at each of the neuron's spikes and decays with tau_adapt;
 *  - a slow synaptic current s (mV/ms), added to the input; a jump of J mV also starts a
 *    current (slow_share * J / tau_slow) * exp(-t / tau_slow), which brings in
 *    slow_share * J mV more over tau_slow.
 *
 *  It can also draw the culture's background noise itself (noise_interval > 0): each neuron
 *  its own xoshiro128++ generator (state noise_s0..noise_s3), redrawn every noise_interval
 *  steps as an Irwin-Hall(4) current noise_mean + noise_sd * z in single precision, the very
 *  values sim_network draws (sim_network/kernels.py) -- no current generator per neuron.
 *
 *  With adapt_increment = 0, slow_share = 0 and no noise it is NEST's izhikevich with
 *  consistent_integration. sim_network/kernels.py is the reference for both currents;
 *  docs/nest.md says how the step orders match.
 *
 *  Part of NeuVision (GPL-3.0-or-later), built against NEST (GPL-2.0-or-later).
 */

#ifndef IZHIKEVICH_NEUVISION_H
#define IZHIKEVICH_NEUVISION_H

#include "archiving_node.h"
#include "connection.h"
#include "event.h"
#include "nest_types.h"
#include "recordables_map.h"
#include "ring_buffer.h"
#include "universal_data_logger.h"

#include <cstdint>

namespace neuvision
{

void register_izhikevich_neuvision( const std::string& name );

class izhikevich_neuvision : public nest::ArchivingNode
{
public:
  izhikevich_neuvision();
  izhikevich_neuvision( const izhikevich_neuvision& );

  using nest::Node::handle;
  using nest::Node::handles_test_event;

  void handle( nest::DataLoggingRequest& ) override;
  void handle( nest::SpikeEvent& ) override;
  void handle( nest::CurrentEvent& ) override;

  size_t handles_test_event( nest::DataLoggingRequest&, size_t ) override;
  size_t handles_test_event( nest::SpikeEvent&, size_t ) override;
  size_t handles_test_event( nest::CurrentEvent&, size_t ) override;
  size_t send_test_event( nest::Node&, size_t, nest::synindex, bool ) override;

  void get_status( Dictionary& ) const override;
  void set_status( const Dictionary& ) override;

private:
  friend class nest::RecordablesMap< izhikevich_neuvision >;
  friend class nest::UniversalDataLogger< izhikevich_neuvision >;

  void init_buffers_() override;
  void pre_run_hook() override;
  void update( nest::Time const&, const long, const long ) override;

  struct Parameters_
  {
    double a_;
    double b_;
    double c_;                //!< after-spike reset of V_m (mV)
    double d_;                //!< after-spike increment of U_m
    double I_e_;              //!< constant input current (mV/ms)
    double V_th_;             //!< spike threshold (mV)
    double V_min_;            //!< lower bound of V_m (mV)
    double adapt_increment_;  //!< rise of the adaptation current per spike (mV/ms)
    double tau_adapt_;        //!< decay time of the adaptation current (ms)
    double slow_share_;       //!< mV brought in by the slow current per mV of jump
    double tau_slow_;         //!< decay time of the slow current (ms)
    double noise_mean_;       //!< mean of the noise current (mV/ms)
    double noise_sd_;         //!< its standard deviation (mV/ms)
    long noise_interval_;     //!< steps between draws; 0: no noise drawn here

    Parameters_();
    void get( Dictionary& ) const;
    void set( const Dictionary&, nest::Node* );
  };

  struct State_
  {
    double v_;  //!< membrane potential (mV)
    double u_;  //!< recovery variable
    double w_;  //!< adaptation current (mV/ms)
    double s_;  //!< slow synaptic current (mV/ms)
    double I_;  //!< current from current generators, read at the end of a step
    uint32_t rng_[ 4 ];  //!< the noise generator's xoshiro128++ state
    float noise_;        //!< the noise current of the window (single precision, as drawn)

    State_();
    void get( Dictionary& ) const;
    void set( const Dictionary&, nest::Node* );
  };

  struct Buffers_
  {
    Buffers_( izhikevich_neuvision& );
    Buffers_( const Buffers_&, izhikevich_neuvision& );
    nest::UniversalDataLogger< izhikevich_neuvision > logger_;
    nest::RingBuffer spikes_;
    nest::RingBuffer currents_;
  };

  struct Variables_
  {
    double adapt_decay_;  //!< exp(-h / tau_adapt)
    double slow_decay_;   //!< exp(-h / tau_slow)
    double slow_gain_;    //!< slow_share / tau_slow (per ms)
  };

  double
  get_V_m_() const
  {
    return S_.v_;
  }
  double
  get_U_m_() const
  {
    return S_.u_;
  }
  double
  get_I_adapt_() const
  {
    return S_.w_;
  }
  double
  get_I_slow_() const
  {
    return S_.s_;
  }

  Parameters_ P_;
  State_ S_;
  Variables_ V_;
  Buffers_ B_;

  static nest::RecordablesMap< izhikevich_neuvision > recordablesMap_;
};

inline size_t
izhikevich_neuvision::send_test_event( nest::Node& target, size_t receptor_type, nest::synindex, bool )
{
  nest::SpikeEvent e;
  e.set_sender( *this );
  return target.handles_test_event( e, receptor_type );
}

inline size_t
izhikevich_neuvision::handles_test_event( nest::SpikeEvent&, size_t receptor_type )
{
  if ( receptor_type != 0 )
  {
    throw nest::UnknownReceptorType( receptor_type, get_name() );
  }
  return 0;
}

inline size_t
izhikevich_neuvision::handles_test_event( nest::CurrentEvent&, size_t receptor_type )
{
  if ( receptor_type != 0 )
  {
    throw nest::UnknownReceptorType( receptor_type, get_name() );
  }
  return 0;
}

inline size_t
izhikevich_neuvision::handles_test_event( nest::DataLoggingRequest& dlr, size_t receptor_type )
{
  if ( receptor_type != 0 )
  {
    throw nest::UnknownReceptorType( receptor_type, get_name() );
  }
  return B_.logger_.connect_logging_device( dlr, recordablesMap_ );
}

}  // namespace neuvision

#endif  // IZHIKEVICH_NEUVISION_H
